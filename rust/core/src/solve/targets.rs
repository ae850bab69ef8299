//! Targets: each selected vertex pulled towards a position set from outside.
//!
//! The inertia term of projective dynamics (Bouaziz et al. 2014) is exactly
//! this: identity rows weighted by `m/h²`, projecting to the predicted
//! position `x_n + h·v_n`. The caller sets the targets before every solve;
//! the projection is constant within a solve.

use glam::Vec3;

use super::constraint::{Constraint, Context, Rows};
use crate::{Error, Result};

/// Identity rows over a set of vertices, projecting to stored targets.
#[derive(Debug, Clone)]
pub struct Targets {
    name: String,
    rows: Rows,
    targets: Vec<Vec3>,
}

impl Targets {
    /// Targets on `vertices`, initially at the origin (set them before solving).
    pub fn new(name: impl Into<String>, vertices: &[u32]) -> Self {
        Targets { name: name.into(), rows: Rows::identity(vertices), targets: vec![Vec3::ZERO; vertices.len()] }
    }

    /// One target per row.
    pub fn set_targets(&mut self, targets: &[Vec3]) -> Result<()> {
        if targets.len() != self.targets.len() {
            return Err(Error::invalid(format!(
                "constraint {}: {} targets given for {} rows",
                self.name,
                targets.len(),
                self.targets.len()
            )));
        }
        crate::mesh::validate_positions("targets", targets)?;
        self.targets.copy_from_slice(targets);
        Ok(())
    }
}

impl Constraint for Targets {
    fn name(&self) -> &str {
        &self.name
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    fn is_constant(&self) -> bool {
        true
    }

    #[inline]
    fn project_row(&self, _context: &Context<'_>, row: usize) -> Vec3 {
        self.targets[row]
    }

    fn replace_targets(&mut self, targets: &[Vec3]) -> Option<Result<()>> {
        Some(self.set_targets(targets))
    }
}
