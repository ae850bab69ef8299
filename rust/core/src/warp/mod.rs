//! UV Warp: content-aware parameterisation warps (seed 001, Koniaris et al.
//! 2015) by hierarchical position-based dynamics on a UV-space grid.
//!
//! Rigid texture detail (scales, plates, printed marks) keeps its shape and
//! size while the surface under it stretches: the UV domain of every UDIM tile
//! is covered by a grid (one node per texel centre) that is warped so that
//! segments in rigid regions keep their rest length on the deformed surface;
//! the warp is then inverted into a float32 "UV redirection" texture.
//!
//! Conventions (shared by the Python API and the EXR files):
//! - a tile's grid is `width × height` texels (powers of two, 8 … 16384);
//! - arrays are `(height, width[, channels])`, row-major, **row 0 is the
//!   lowest `v`**: texel `(row j, column i)` covers `u ∈ [i/width, (i+1)/width)`,
//!   `v ∈ [j/height, (j+1)/height)` of its tile, which is Blender's own
//!   bottom-up order of `Image.pixels`;
//! - redirections are absolute UVs (UDIM offset included): a point whose UV is
//!   `t` samples its texture at `redirection(t)`.
//!
//! Modules: [`raster`] (watertight fixed-point rasteriser), [`tiles`] (UDIM
//! split, charts), [`layout`] (the UV layout rasterised per tile, automatic
//! mask, surface metrics), [`maps`] (rigidity/mask hierarchies), [`images`]
//! (per-texel images for the add-on: corner values, resampling, stretch), [`solver`]
//! (the PBD hierarchy), [`invert`] (redirection), [`metrics`], [`exr`].
//!
//! The method is the subject of US patent 9,959,662 (Disney).

pub mod exr;
pub mod images;
pub mod fixtures;
pub mod invert;
pub mod layout;
pub mod maps;
pub mod metrics;
pub mod raster;
pub mod solver;
pub mod sweep;
pub mod tiles;

#[cfg(test)]
mod tests;

use glam::{Vec2, Vec3};

use crate::error::check_allocation;
use crate::mesh::MeshInput;
use crate::{Error, Result};

pub use layout::TileLayout;
pub use metrics::{Stats, WarpMetrics};
pub use solver::Solver;
pub use tiles::{udim_offset, UvMesh};

/// Bytes per texel of a tile's state, all levels and buffers counted
/// (finest level ≈ 40 B with the multigrid's saved iterate, coarser levels
/// ≈ 66 B × 1/3 with its forcing, construction temporaries).
pub const BYTES_PER_TEXEL: u64 = 70;
/// Default memory limit: enough for 4096² tiles, not for 16384².
pub const DEFAULT_MEMORY_LIMIT: u64 = 3 << 30;

/// Under-relaxation of each projection: a rigid segment moves half way to its
/// rest length per visit. Full steps (1.0) converge a little faster on smooth
/// fixtures but oscillate and fold where neighbouring constraints disagree
/// (Spot's small, unevenly stretched triangles).
pub(crate) const RELAXATION: f32 = 0.5;

/// Solver settings.
#[derive(Debug, Clone, PartialEq)]
pub struct WarpSettings {
    /// The default solver ([`solver::Variant::Cascade`]): PBD iterations on
    /// the finest level. A cold solve (from the identity) runs
    /// `iterations · 2^l` on level `l` (at most 96, or `iterations` if
    /// larger); a warm solve runs `iterations` on the levels down to 256²
    /// only (the coarser ones hold little change of a warm-started warp).
    /// With [`solver::Variant::Multigrid`]: cycles per frame (a cold solve
    /// runs one more on every level from the coarsest up); each brings the
    /// warp closer to the finest level's fixed point.
    pub iterations: u32,
    /// Fraction in [0, 1] by which each projected segment is rotated back
    /// towards its rest direction (times its rigidity).
    pub orientation: f32,
    /// Global smoothing factor `s` in [0, 1] of rigid regions (seed eq. 4).
    pub smoothing: f32,
    /// Start each solve from the previous frame's warp (`false`: from the
    /// identity, deterministic whatever was solved before).
    pub warm_start: bool,
    /// Refuse grids whose state would need more than this many bytes.
    pub memory_limit: u64,
    /// Measure deformed segment lengths on the surface under the *warped*
    /// segment (seed eq. 1 literally, finest level only, within one chart)
    /// instead of under the rest segment. Off by default: on meshes whose
    /// triangles have very different metrics (Spot) the literal form makes
    /// the projection chatter between triangles and fold.
    pub sample_warped: bool,
}

impl Default for WarpSettings {
    fn default() -> Self {
        WarpSettings { iterations: 4, orientation: 0.05, smoothing: 0.1, warm_start: true, memory_limit: DEFAULT_MEMORY_LIMIT, sample_warped: false }
    }
}

impl WarpSettings {
    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 || self.iterations > 10_000 {
            return Err(Error::invalid(format!("iterations must be between 1 and 10000, not {}", self.iterations)));
        }
        for (name, v) in [("orientation", self.orientation), ("smoothing", self.smoothing)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(Error::invalid(format!("{name} must be in [0, 1], not {v}")));
            }
        }
        Ok(())
    }

    /// The settings as text pairs (for EXR metadata and reports).
    pub fn describe(&self) -> Vec<(String, String)> {
        vec![
            ("iterations".into(), self.iterations.to_string()),
            ("orientation".into(), self.orientation.to_string()),
            ("smoothing".into(), self.smoothing.to_string()),
            ("warm_start".into(), self.warm_start.to_string()),
            ("sample_warped".into(), self.sample_warped.to_string()),
        ]
    }
}

/// Rigidity and optional warp mask of one UDIM tile, `(height, width)` arrays
/// flattened row-major, values in [0, 1].
#[derive(Debug, Clone, Copy)]
pub struct TileMaps<'a> {
    pub udim: u32,
    pub rigidity: &'a [f32],
    pub mask: Option<&'a [f32]>,
}

/// Checks a grid side: a power of two in [8, 16384].
pub fn check_grid_size(width: usize, height: usize) -> Result<()> {
    for (name, v) in [("width", width), ("height", height)] {
        if !v.is_power_of_two() || !(8..=16384).contains(&v) {
            return Err(Error::invalid(format!("grid {name} must be a power of two between 8 and 16384, not {v}")));
        }
    }
    Ok(())
}

/// One tile's grid, solver and latest redirection.
#[derive(Debug, Clone)]
pub struct TileWarp {
    pub layout: TileLayout,
    pub solver: Solver,
    /// Latest redirection: `(height, width, 2)` absolute UVs.
    pub redirection: Vec<f32>,
    /// Per-triangle metrics of the latest deformed surface.
    gd_tri: Vec<[f32; 3]>,
    /// Wall time (ms) of the last solve's stages: surface metrics, solver,
    /// inversion (for the benchmark's breakdown).
    pub last_stage_ms: [f64; 3],
}

impl TileWarp {
    pub fn udim(&self) -> u32 {
        self.layout.udim
    }

    /// Validity: 1 inside UV charts, 0 outside (`(height, width)`).
    pub fn validity(&self) -> &[u8] {
        &self.layout.covered
    }

    /// Fine-level displacement (texels) of every node.
    pub fn displacement(&self) -> (&[f32], &[f32]) {
        (&self.solver.levels[0].dx, &self.solver.levels[0].dy)
    }

    fn identity_redirection(&mut self) {
        let (w, h) = (self.layout.width, self.layout.height);
        let (dx, dy) = (&self.solver.levels[0].dx, &self.solver.levels[0].dy);
        invert::invert(dx, dy, w, h, udim_offset(self.layout.udim), &mut self.redirection);
    }
}

/// What [`UvWarp::converge`] reached (the largest over the tiles).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Convergence {
    /// Multigrid cycles run.
    pub cycles: usize,
    /// The largest change of a node (texels) in the last cycle.
    pub cycle_change: f32,
    /// The largest change of a node (texels) in the last of the finest
    /// level's plain iterations that followed.
    pub iteration_change: f32,
}

/// A UV warp of one mesh: one grid per UDIM tile its UVs touch.
#[derive(Debug, Clone)]
pub struct UvWarp {
    pub settings: WarpSettings,
    pub mesh: UvMesh,
    pub width: usize,
    pub height: usize,
    pub tiles: Vec<TileWarp>,
    solved: bool,
}

impl UvWarp {
    /// Prepares the warp: validates everything, rasterises the UV layout of
    /// every tile, builds the rigidity and mask hierarchies. Every tile the
    /// UVs touch needs its [`TileMaps`]; maps of tiles the UVs do not touch
    /// are refused (they are almost always a mistake).
    pub fn new(rest: MeshInput<'_>, corner_uvs: &[Vec2], width: usize, height: usize, maps: &[TileMaps<'_>], settings: WarpSettings) -> Result<Self> {
        settings.validate()?;
        check_grid_size(width, height)?;
        let mesh = UvMesh::new(rest, corner_uvs)?;
        let texels = (width * height) as u64;
        check_allocation::<[u8; BYTES_PER_TEXEL as usize]>(
            &format!("a UV warp of {} tile(s) of {width}×{height}", mesh.tiles.len()),
            texels * mesh.tiles.len() as u64,
            settings.memory_limit,
        )?;
        for m in maps {
            if !mesh.tiles.contains_key(&m.udim) {
                let have: Vec<String> = mesh.tiles.keys().map(|k| k.to_string()).collect();
                return Err(Error::invalid(format!(
                    "a rigidity map was given for UDIM tile {}, but the UVs only touch tile(s) {}",
                    m.udim,
                    have.join(", ")
                )));
            }
            maps::check_image("rigidity", m.udim, m.rigidity, width, height)?;
            if let Some(mask) = m.mask {
                maps::check_image("mask", m.udim, mask, width, height)?;
            }
        }
        let mut tiles = Vec::new();
        for (&udim, tris) in &mesh.tiles {
            let Some(m) = maps.iter().find(|m| m.udim == udim) else {
                return Err(Error::invalid(format!(
                    "the UVs touch UDIM tile {udim} but no rigidity map was given for it (give one map per tile: {})",
                    mesh.tiles.keys().map(|k| k.to_string()).collect::<Vec<_>>().join(", ")
                )));
            };
            let layout = TileLayout::new(&mesh, udim, tris, width, height);
            let go_tri = layout.triangle_metrics(&mesh, rest.positions);
            let mask: Vec<u8> = match m.mask {
                Some(user) => layout.interior.iter().zip(user).map(|(&a, &u)| if a == 0 { 0 } else { (u.clamp(0.0, 1.0) * 255.0).round() as u8 }).collect(),
                None => layout.interior.iter().map(|&a| a * 255).collect(),
            };
            let mut tri_chart: Vec<u32> = layout.tris.iter().map(|&t| mesh.tri_chart[t as usize]).collect();
            tri_chart.push(u32::MAX);
            let solver = Solver::new(width, height, m.rigidity, mask, &layout.ids, go_tri.clone(), tri_chart);
            let mut tile = TileWarp { layout, solver, redirection: vec![0.0; 2 * width * height], gd_tri: go_tri, last_stage_ms: [0.0; 3] };
            tile.identity_redirection();
            tiles.push(tile);
        }
        Ok(UvWarp { settings, mesh, width, height, tiles, solved: false })
    }

    /// Solves every tile for this frame's deformed positions and updates the
    /// redirections. Warm-started from the previous solve unless
    /// `settings.warm_start` is off or nothing was solved yet.
    pub fn solve(&mut self, deformed: &[Vec3]) -> Result<()> {
        self.mesh.check_positions("deformed positions", deformed)?;
        let warm = self.settings.warm_start && self.solved;
        for tile in &mut self.tiles {
            let t0 = std::time::Instant::now();
            tile.gd_tri = tile.layout.triangle_metrics(&self.mesh, deformed);
            let t1 = std::time::Instant::now();
            tile.solver.solve(&tile.layout.ids, &tile.gd_tri, warm, &self.settings);
            let t2 = std::time::Instant::now();
            let (w, h) = (self.width, self.height);
            let lv = &tile.solver.levels[0];
            invert::invert(&lv.dx, &lv.dy, w, h, udim_offset(tile.layout.udim), &mut tile.redirection);
            let ms = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f64() * 1e3;
            tile.last_stage_ms = [ms(t0, t1), ms(t1, t2), ms(t2, std::time::Instant::now())];
        }
        self.solved = true;
        Ok(())
    }

    /// Chooses the solver of every tile (benchmarks and tests compare them);
    /// the next solve starts from the identity.
    #[doc(hidden)]
    pub fn set_variant(&mut self, variant: solver::Variant) {
        for tile in &mut self.tiles {
            tile.solver.set_variant(variant);
        }
    }

    /// Multigrid only: Anderson acceleration of the finest cycles (see
    /// `solver::Solver::set_anderson`).
    #[doc(hidden)]
    pub fn set_anderson(&mut self, depth: usize, across_frames: bool) {
        for tile in &mut self.tiles {
            tile.solver.set_anderson(depth, across_frames);
        }
    }

    /// Continues the last solve until it has converged: the converged warp
    /// `x_∞` convergence errors are measured against (issue 28: positions
    /// change by less than `tolerance` texels in an iteration). Runs
    /// multigrid cycles (at most `max_cycles`) until a cycle moves no node by
    /// more than `tolerance`, then checks the finest level's own iteration:
    /// `check` plain iterations, of which the last must move no node by more
    /// than `tolerance` either (a fixed point of the cycles that the finest
    /// level would leave is not `x_∞`). Repairs folds (none expected) and
    /// inverts. Needs the [`solver::Variant::Multigrid`] solver. For
    /// benchmarks and tests.
    #[doc(hidden)]
    pub fn converge(&mut self, deformed: &[Vec3], tolerance: f32, max_cycles: usize, check: usize) -> Result<Convergence> {
        self.mesh.check_positions("deformed positions", deformed)?;
        let mut out = Convergence::default();
        let settings = WarpSettings { iterations: 1, ..self.settings.clone() };
        for tile in &mut self.tiles {
            if tile.solver.variant() != solver::Variant::Multigrid {
                return Err(Error::invalid("converge needs the multigrid solver"));
            }
            let gd = tile.layout.triangle_metrics(&self.mesh, deformed);
            let ids = &tile.layout.ids;
            let (mut cycles, mut change) = (0, f32::INFINITY);
            while cycles < max_cycles && change >= tolerance {
                let (bx, by) = (tile.solver.levels[0].dx.clone(), tile.solver.levels[0].dy.clone());
                tile.solver.solve(ids, &gd, true, &settings);
                let lv = &tile.solver.levels[0];
                change = lv.dx.iter().zip(&bx).chain(lv.dy.iter().zip(&by)).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                cycles += 1;
            }
            let plain = tile.solver.iterate_finest_plain(ids, &gd, check, &settings);
            out.cycles = out.cycles.max(cycles);
            out.cycle_change = out.cycle_change.max(change);
            out.iteration_change = out.iteration_change.max(plain);
            tile.solver.repair();
            let (w, h) = (self.width, self.height);
            let lv = &tile.solver.levels[0];
            invert::invert(&lv.dx, &lv.dy, w, h, udim_offset(tile.layout.udim), &mut tile.redirection);
        }
        Ok(out)
    }

    /// Forgets the previous frame: the next solve starts from the identity.
    pub fn reset(&mut self) {
        for tile in &mut self.tiles {
            tile.solver.reset();
            tile.identity_redirection();
        }
        self.solved = false;
    }

    pub fn tile(&self, udim: u32) -> Option<&TileWarp> {
        self.tiles.iter().find(|t| t.udim() == udim)
    }

    /// Measures the current warp of every tile against `deformed` positions.
    pub fn metrics(&self, deformed: &[Vec3]) -> Result<Vec<WarpMetrics>> {
        self.mesh.check_positions("deformed positions", deformed)?;
        Ok(self
            .tiles
            .iter()
            .map(|tile| {
                let gd = tile.layout.triangle_metrics(&self.mesh, deformed);
                let lv = &tile.solver.levels[0];
                let off = udim_offset(tile.udim());
                metrics::measure(&metrics::MeasureInput {
                    udim: tile.udim(),
                    w: self.width,
                    h: self.height,
                    ids: &tile.layout.ids,
                    interior: &tile.layout.interior,
                    rigidity: &lv.rig,
                    mask: &lv.mask,
                    go_tri: tile.solver.rest_metrics(),
                    gd_tri: &gd,
                    dx: &lv.dx,
                    dy: &lv.dy,
                    redirection: &tile.redirection,
                    offset: [off.x, off.y],
                })
            })
            .collect())
    }

    /// EXR metadata describing this warp.
    pub fn exr_metadata(&self, udim: u32) -> Vec<(String, String)> {
        let mut m = self.settings.describe();
        m.push(("udim".into(), udim.to_string()));
        m.push(("grid".into(), format!("{}x{}", self.width, self.height)));
        m.push(("channels".into(), "R,G = redirected absolute UV; B = 1 inside UV charts".into()));
        m.push(("rows".into(), "stored top row first (standard EXR); row 0 of Tegument arrays is the lowest v".into()));
        m
    }

    /// Writes a tile's redirection as an EXR (R, G = UV, B = validity).
    pub fn write_exr(&self, udim: u32, path: &std::path::Path) -> Result<()> {
        let tile = self.tile(udim).ok_or_else(|| Error::invalid(format!("this warp has no UDIM tile {udim}")))?;
        let n = self.width * self.height;
        let mut data = Vec::with_capacity(3 * n);
        for i in 0..n {
            data.extend_from_slice(&[tile.redirection[2 * i], tile.redirection[2 * i + 1], tile.layout.covered[i] as f32]);
        }
        exr::write_exr(path, self.width, self.height, 3, &data, &self.exr_metadata(udim))
    }
}
