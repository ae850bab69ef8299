//! The UV mesh: polygons fan-triangulated in corner order, triangles grouped
//! into UDIM tiles (each tile gets its own grid), and UV charts found by
//! walking edges whose two corners agree on vertex *and* UV.

use std::collections::{BTreeMap, HashMap};

use glam::{Vec2, Vec3};

use crate::mesh::MeshInput;
use crate::{Error, Result};

/// One triangle of the fan triangulation: three corner indices.
pub type Tri = [u32; 3];

/// A mesh prepared for UV warping.
#[derive(Debug, Clone)]
pub struct UvMesh {
    pub vertex_count: usize,
    /// Vertex index of every corner.
    pub corner_verts: Vec<u32>,
    /// UV of every corner.
    pub corner_uvs: Vec<Vec2>,
    /// All triangles (corner triples).
    pub tris: Vec<Tri>,
    /// Chart index of every triangle.
    pub tri_chart: Vec<u32>,
    pub chart_count: usize,
    /// Triangle indices of each UDIM tile (ordered by UDIM number).
    pub tiles: BTreeMap<u32, Vec<u32>>,
}

/// UDIM number of tile `(u, v)`: 1001 + u + 10·v.
pub fn udim_of(tile_u: i64, tile_v: i64) -> u32 {
    (1001 + tile_u + 10 * tile_v) as u32
}

/// Offset `(u, v)` of a UDIM tile's lower-left corner.
pub fn udim_offset(udim: u32) -> Vec2 {
    let k = udim as i64 - 1001;
    Vec2::new((k % 10) as f32, (k / 10) as f32)
}

impl UvMesh {
    /// Validates the mesh and UVs and prepares triangles, tiles and charts.
    pub fn new(input: MeshInput<'_>, corner_uvs: &[Vec2]) -> Result<Self> {
        let offsets = input.validate()?;
        let corners = input.corner_verts.len();
        check_corner_uvs(corner_uvs, corners)?;
        let mut tris = Vec::with_capacity(corners);
        for p in 0..input.polygon_sizes.len() {
            let (s, e) = (offsets[p], offsets[p + 1]);
            for k in s + 1..e - 1 {
                tris.push([s, k, k + 1]);
            }
        }
        let mut tiles: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for (t, tri) in tris.iter().enumerate() {
            let c = tri.iter().fold(Vec2::ZERO, |a, &k| a + corner_uvs[k as usize]) / 3.0;
            // A triangle hanging slightly over the lower or left edge of the
            // UV range (common in 0–1 layouts) still belongs to the first tile.
            let tile = |x: f32| if (-0.25..0.0).contains(&x) { 0 } else { x.floor() as i64 };
            let (tu, tv) = (tile(c.x), tile(c.y));
            if !(0..10).contains(&tu) || !(0..1000).contains(&tv) {
                return Err(Error::invalid(format!(
                    "a triangle of polygon at corners {}..{} has its UV centre at ({:.3}, {:.3}), outside the UDIM range (u in [0, 10), v ≥ 0)",
                    tri[0], tri[2], c.x, c.y
                )));
            }
            tiles.entry(udim_of(tu, tv)).or_default().push(t as u32);
        }
        let corner_verts: Vec<u32> = input.corner_verts.iter().map(|&v| v as u32).collect();
        let (tri_chart, chart_count) = charts(&tris, &corner_verts, corner_uvs);
        Ok(UvMesh {
            vertex_count: input.positions.len(),
            corner_verts,
            corner_uvs: corner_uvs.to_vec(),
            tris,
            tri_chart,
            chart_count,
            tiles,
        })
    }

    /// Checks a position array against the mesh.
    pub fn check_positions(&self, what: &str, positions: &[Vec3]) -> Result<()> {
        if positions.len() != self.vertex_count {
            return Err(Error::Topology(format!(
                "{what} has {} vertices but the mesh the warp was built for has {}",
                positions.len(),
                self.vertex_count
            )));
        }
        crate::mesh::validate_positions(what, positions)
    }
}

/// One finite UV per face corner.
pub(crate) fn check_corner_uvs(corner_uvs: &[Vec2], corners: usize) -> Result<()> {
    if corner_uvs.len() != corners {
        return Err(Error::invalid(format!(
            "corner_uvs has {} UVs but the mesh has {corners} face corners (one UV per corner, in Blender's corner order)",
            corner_uvs.len()
        )));
    }
    if let Some(c) = corner_uvs.iter().position(|uv| !uv.is_finite()) {
        return Err(Error::invalid(format!("corner_uvs: the UV of corner {c} is not finite ({:?})", corner_uvs[c].to_array())));
    }
    Ok(())
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

/// Union-find over triangles sharing an edge with the same vertices and UVs.
fn charts(tris: &[Tri], corner_verts: &[u32], uvs: &[Vec2]) -> (Vec<u32>, usize) {
    let mut parent: Vec<u32> = (0..tris.len() as u32).collect();
    let mut edges: HashMap<(u32, u32, [u32; 4]), u32> = HashMap::with_capacity(tris.len() * 3);
    for (t, tri) in tris.iter().enumerate() {
        for k in 0..3 {
            let (ca, cb) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
            let (mut va, mut vb) = (corner_verts[ca], corner_verts[cb]);
            let (mut ua, mut ub) = (uvs[ca], uvs[cb]);
            if va > vb {
                std::mem::swap(&mut va, &mut vb);
                std::mem::swap(&mut ua, &mut ub);
            }
            let key = (va, vb, [ua.x.to_bits(), ua.y.to_bits(), ub.x.to_bits(), ub.y.to_bits()]);
            match edges.get(&key) {
                Some(&other) => {
                    let (ra, rb) = (find(&mut parent, t as u32), find(&mut parent, other));
                    if ra != rb {
                        parent[ra.max(rb) as usize] = ra.min(rb);
                    }
                }
                None => {
                    edges.insert(key, t as u32);
                }
            }
        }
    }
    let mut ids: HashMap<u32, u32> = HashMap::new();
    let mut chart = vec![0u32; tris.len()];
    for t in 0..tris.len() {
        let r = find(&mut parent, t as u32);
        let n = ids.len() as u32;
        chart[t] = *ids.entry(r).or_insert(n);
    }
    (chart, ids.len())
}
