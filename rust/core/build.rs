//! Tells the tests whether the shared test data (`../shared/data` beside the
//! checkout, or `$TEGUMENT_DATA_DIR`) is there, so that a test needing it is
//! reported as *ignored, with the reason* where it is absent instead of
//! returning early and passing. Under `CI=true` those tests are never ignored:
//! they run and fail, naming the missing path.
//!
//! Only the tests read these cfgs; the library itself is the same either way.

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(shared_data)");
    println!("cargo::rustc-check-cfg=cfg(require_shared_data)");
    println!("cargo::rerun-if-env-changed=TEGUMENT_DATA_DIR");
    println!("cargo::rerun-if-env-changed=CI");
    let root = match std::env::var_os("TEGUMENT_DATA_DIR") {
        Some(dir) => PathBuf::from(dir),
        None => PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    };
    // A missing path keeps the build script stale, so it runs again (and sees
    // the folder) once the data appears.
    println!("cargo::rerun-if-changed={}", root.display());
    if root.is_dir() {
        println!("cargo::rustc-cfg=shared_data");
    } else if std::env::var("CI").as_deref() == Ok("true") {
        println!("cargo::rustc-cfg=require_shared_data");
        println!("cargo::warning=shared test data not found at {} (CI=true: the tests that need it will fail)", root.display());
    }
}
