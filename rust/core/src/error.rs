//! The one error type of the core.
//!
//! Messages name what is wrong and where (which vertex, which corner, which
//! polygon) because they travel unchanged to the artist's status bar.

use std::fmt;

/// Everything the core can refuse or fail at.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// An input array has the wrong length, an index is out of range, a value
    /// is not finite, or a setting is outside its range.
    #[error("{0}")]
    InvalidInput(String),
    /// The mesh cannot be used for the requested operation (for example the
    /// vertex count differs from the bind).
    #[error("{0}")]
    Topology(String),
    /// A request would need more memory than the configured limit.
    #[error("{what} would need {needed_bytes} bytes ({}), more than the limit of {limit_bytes} bytes ({})", human_bytes(*.needed_bytes), human_bytes(*.limit_bytes))]
    TooLarge {
        what: String,
        needed_bytes: u64,
        limit_bytes: u64,
    },
    /// A numerical step failed (for example a factorisation of a singular system).
    #[error("{0}")]
    Numerical(String),
    /// Reading or writing a file failed.
    #[error("{0}")]
    Io(String),
}

/// Shorthand used across the crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Builds an [`Error::InvalidInput`] from anything printable.
    pub fn invalid(message: impl fmt::Display) -> Self {
        Error::InvalidInput(message.to_string())
    }
}

fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {}", UNITS[unit])
}

/// Refuses an allocation of `count` elements of `T` above `limit_bytes`,
/// before anything is allocated.
pub fn check_allocation<T>(what: &str, count: u64, limit_bytes: u64) -> Result<()> {
    let needed_bytes = count.saturating_mul(std::mem::size_of::<T>() as u64);
    if needed_bytes > limit_bytes {
        return Err(Error::TooLarge {
            what: what.to_string(),
            needed_bytes,
            limit_bytes,
        });
    }
    Ok(())
}

/// The default of [`memory_limit`]: 16 GiB.
pub const DEFAULT_MEMORY_LIMIT: u64 = 16 << 30;

/// The process-wide limit for work sized by the input (meshes): the
/// `TEGUMENT_MEMORY_LIMIT` environment variable in bytes, with an optional
/// `K`, `M` or `G` suffix (powers of 1024), read once; [`DEFAULT_MEMORY_LIMIT`]
/// when it is unset or unreadable. A render farm sets it below a node's RAM so
/// that an oversized job fails with a message instead of being killed.
pub fn memory_limit() -> u64 {
    static LIMIT: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *LIMIT.get_or_init(|| {
        std::env::var("TEGUMENT_MEMORY_LIMIT").ok().and_then(|text| parse_bytes(&text)).unwrap_or(DEFAULT_MEMORY_LIMIT)
    })
}

fn parse_bytes(text: &str) -> Option<u64> {
    let text = text.trim();
    let (digits, shift) = match text.chars().last()?.to_ascii_uppercase() {
        'K' => (&text[..text.len() - 1], 10),
        'M' => (&text[..text.len() - 1], 20),
        'G' => (&text[..text.len() - 1], 30),
        _ => (text, 0),
    };
    digits.trim().parse::<u64>().ok()?.checked_mul(1 << shift)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn too_large_names_sizes() {
        let err = check_allocation::<f32>("a 65536² grid", 65536 * 65536, 1 << 30).unwrap_err();
        let text = err.to_string();
        assert!(text.contains("a 65536² grid would need 17179869184 bytes (16.0 GiB)"), "{text}");
        assert!(text.contains("limit of 1073741824 bytes (1.0 GiB)"), "{text}");
    }

    /// The Python bindings catch panics (bugs) at the boundary with
    /// `catch_unwind`; that needs a panic on a rayon worker to unwind back to
    /// the caller instead of aborting the process.
    #[test]
    fn panic_in_parallel_work_reaches_the_caller() {
        use rayon::prelude::*;
        let outcome = std::panic::catch_unwind(|| {
            (0..64).into_par_iter().for_each(|i| {
                if i == 37 {
                    panic!("deliberate panic in task {i}");
                }
            })
        });
        let payload = outcome.expect_err("the panic must reach the caller");
        let text = payload.downcast_ref::<String>().cloned().unwrap_or_default();
        assert_eq!(text, "deliberate panic in task 37");
    }

    #[test]
    fn memory_limit_text() {
        assert_eq!(parse_bytes("1048576"), Some(1 << 20));
        assert_eq!(parse_bytes("64M"), Some(64 << 20));
        assert_eq!(parse_bytes(" 2g "), Some(2 << 30));
        assert_eq!(parse_bytes("lots"), None);
        assert_eq!(parse_bytes(""), None);
        assert_eq!(parse_bytes("99999999999999999999G"), None);
    }
}
