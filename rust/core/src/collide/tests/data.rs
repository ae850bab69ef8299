//! Readers of the CCD data sets in `../shared/data/ccd` (relative to the
//! project root). The data is never copied into the project.
//!
//! When the data folder is absent, `build.rs` leaves out `cfg(shared_data)` and
//! the tests that need it are ignored with [`ABSENT`] as the reason (unless
//! `CI=true`, where they run and fail in [`require`]).

use std::path::{Path, PathBuf};

use glam::DVec3;

/// `<project root>/../shared/data`, or `$TEGUMENT_DATA_DIR`.
pub fn data_root() -> PathBuf {
    if let Ok(dir) = std::env::var("TEGUMENT_DATA_DIR") {
        return PathBuf::from(dir);
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
}

/// The reason a test that needs the data is ignored where it is absent
/// (`#[cfg_attr(not(any(shared_data, require_shared_data)), ignore = …)]`; an
/// attribute needs a literal, so this is the text to copy).
#[allow(dead_code)]
pub const ABSENT: &str = "../shared/data is absent: the shared test data sits beside the checkout (or set $TEGUMENT_DATA_DIR)";

/// The path `<data root>/<relative>`; panics, naming it, when it is missing
/// (a test calling this runs only where the data folder is, or under CI).
pub fn require(relative: &str) -> PathBuf {
    let path = data_root().join(relative);
    assert!(
        path.exists(),
        "data set not found at {} (expected ../shared/data relative to the project root, or $TEGUMENT_DATA_DIR)",
        path.display()
    );
    path
}

fn rational(num: &str, den: &str, path: &Path, line: usize) -> f64 {
    let n: i128 = num.trim().parse().unwrap_or_else(|e| panic!("{}:{line}: numerator {num:?}: {e}", path.display()));
    let d: i128 = den.trim().parse().unwrap_or_else(|e| panic!("{}:{line}: denominator {den:?}: {e}", path.display()));
    // Exact conversion needs |n| < 2^53 and a power-of-two denominator.
    assert!(n.unsigned_abs() < (1u128 << 53), "{}:{line}: numerator {n} not exact in f64", path.display());
    assert!(d > 0 && (d & (d - 1)) == 0, "{}:{line}: denominator {d} is not a power of two", path.display());
    n as f64 / d as f64
}

/// One query: the 8 points in the file's row order, and the ground truth if
/// the file carries it.
pub struct Query {
    pub points: [DVec3; 8],
    pub truth: Option<bool>,
}

/// Reads a query CSV with 6 (`xn,xd,yn,yd,zn,zd`) or 7 (`…,gt`) columns.
pub fn read_queries(path: &Path) -> Vec<Query> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let rows: Vec<(DVec3, Option<bool>)> = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, line)| {
            let cols: Vec<&str> = line.split(',').collect();
            assert!(cols.len() == 6 || cols.len() == 7, "{}:{}: {} columns", path.display(), i + 1, cols.len());
            let p = DVec3::new(
                rational(cols[0], cols[1], path, i + 1),
                rational(cols[2], cols[3], path, i + 1),
                rational(cols[4], cols[5], path, i + 1),
            );
            let truth = cols.get(6).map(|g| g.trim() == "1");
            (p, truth)
        })
        .collect();
    assert!(rows.len() % 8 == 0, "{}: {} rows is not a multiple of 8", path.display(), rows.len());
    rows.chunks(8)
        .map(|chunk| {
            let mut points = [DVec3::ZERO; 8];
            for (k, (p, _)) in chunk.iter().enumerate() {
                points[k] = *p;
            }
            Query { points, truth: chunk[0].1 }
        })
        .collect()
}

/// Reads a JSON array of booleans.
pub fn read_bools(path: &Path) -> Vec<bool> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.trim()
        .trim_start_matches('[')
        .trim_end_matches(']')
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| match s.trim() {
            "true" => true,
            "false" => false,
            other => panic!("{}: not a boolean: {other:?}", path.display()),
        })
        .collect()
}

/// Reads a JSON array of `[a, b]` integer pairs.
pub fn read_pairs(path: &Path) -> Vec<[usize; 2]> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let numbers: Vec<usize> = text
        .split(|c: char| !c.is_ascii_digit())
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().expect("integer"))
        .collect();
    assert!(numbers.len() % 2 == 0, "{}: odd number of ids", path.display());
    numbers.chunks(2).map(|c| [c[0], c[1]]).collect()
}

/// Reads a binary little-endian PLY with double x, y, z vertices and
/// `list uchar int` faces (triangles only).
pub fn read_ply(path: &Path) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let marker = b"end_header\n";
    let end = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .unwrap_or_else(|| panic!("{}: no end_header", path.display()))
        + marker.len();
    let header = std::str::from_utf8(&bytes[..end]).expect("ASCII header");
    assert!(header.contains("format binary_little_endian 1.0"), "{}: not binary little-endian", path.display());
    let count = |element: &str| -> usize {
        header
            .lines()
            .find_map(|l| l.strip_prefix(&format!("element {element} ")))
            .and_then(|n| n.trim().parse().ok())
            .unwrap_or_else(|| panic!("{}: no element {element}", path.display()))
    };
    let (nv, nf) = (count("vertex"), count("face"));
    let mut at = end;
    let f64_at = |at: &mut usize| {
        let v = f64::from_le_bytes(bytes[*at..*at + 8].try_into().unwrap());
        *at += 8;
        v
    };
    let mut vertices = Vec::with_capacity(nv);
    for _ in 0..nv {
        let x = f64_at(&mut at);
        let y = f64_at(&mut at);
        let z = f64_at(&mut at);
        vertices.push(DVec3::new(x, y, z));
    }
    let mut faces = Vec::with_capacity(nf);
    for f in 0..nf {
        let n = bytes[at];
        at += 1;
        assert_eq!(n, 3, "{}: face {f} has {n} corners", path.display());
        let mut tri = [0u32; 3];
        for corner in &mut tri {
            *corner = i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as u32;
            at += 4;
        }
        faces.push(tri);
    }
    assert_eq!(at, bytes.len(), "{}: trailing bytes", path.display());
    (vertices, faces)
}
