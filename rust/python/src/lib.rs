//! `tegument._native`: the numpy face of `tegument-core`.
//!
//! This crate only converts: numpy arrays in (checked for dtype, shape and
//! layout), core results out, core errors into `tegument.TegumentError`.
//! Numerics belong in `rust/core`.

use pyo3::prelude::*;

mod collide;
mod convert;
mod mesh;
mod pyramid;
mod warp;

pub use convert::TegumentError;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("TegumentError", m.py().get_type::<TegumentError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    mesh::register(m)?;
    collide::register(m)?;
    pyramid::register(m)?;
    warp::register(m)?;
    Ok(())
}
