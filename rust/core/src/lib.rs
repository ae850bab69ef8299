//! Tegument's numerics, free of Python and Blender.
//!
//! Every public entry point validates what it is given and returns
//! [`Result<_, Error>`]: callers (the Python bindings, benchmarks, tests) decide
//! how to show a failure; nothing in here panics on user data.

pub mod collide;
pub mod error;
pub mod mesh;
pub mod pyramid;
pub mod sequence;
pub mod solve;
pub mod strain;
pub mod warp;

pub use error::{Error, Result};
pub use mesh::{MeshInput, Topology, TopologyReport};
