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
}
