//! Split seams (issue 26): a mesh whose vertices are split where a UV or a
//! sharp normal changes, as glTF, FBX and USD importers deliver it, deforms
//! exactly like the same mesh welded, and its seams never open.

use glam::Vec3;

use super::{Sequence, StepOptions, StrainMode, StrainOptions};
use crate::collide::{audit, AuditParams, Collider, ColliderSettings};
use crate::mesh::shapes::{cylinder, quad_sphere, PolyMesh};
use crate::mesh::MeshInput;
use crate::pyramid::{Closeness, DeformerOptions};
use crate::strain::MaxStretch;

/// `mesh` split into shells by `shell_of(polygon centroid)`: the first shell
/// to use a vertex keeps its index, every other shell gets a copy appended at
/// the end. Returns the split mesh and, per vertex of it, the original vertex.
fn split(mesh: &PolyMesh, shell_of: impl Fn(Vec3) -> usize) -> (PolyMesh, Vec<usize>) {
    let mut out = PolyMesh { positions: mesh.positions.clone(), ..Default::default() };
    let mut original: Vec<usize> = (0..mesh.positions.len()).collect();
    let mut owner: Vec<Option<usize>> = vec![None; mesh.positions.len()];
    let mut copies: std::collections::HashMap<(usize, usize), usize> = Default::default();
    let mut start = 0;
    for &size in &mesh.polygon_sizes {
        let corners: Vec<usize> = mesh.corner_verts[start..start + size as usize].iter().map(|&v| v as usize).collect();
        start += size as usize;
        let centroid = corners.iter().map(|&v| mesh.positions[v]).sum::<Vec3>() / corners.len() as f32;
        let shell = shell_of(centroid);
        let renumbered: Vec<usize> = corners
            .iter()
            .map(|&v| match owner[v] {
                None => {
                    owner[v] = Some(shell);
                    v
                }
                Some(s) if s == shell => v,
                Some(_) => *copies.entry((v, shell)).or_insert_with(|| {
                    out.positions.push(mesh.positions[v]);
                    original.push(v);
                    out.positions.len() - 1
                }),
            })
            .collect();
        out.push_polygon(&renumbered);
    }
    (out, original)
}

/// A quad sphere cut into four shells along two great circles.
fn split_sphere() -> (PolyMesh, PolyMesh, Vec<usize>) {
    let whole = quad_sphere(8, 1.0);
    let (split, original) = split(&whole, |c| (c.x > 0.0) as usize + 2 * (c.y > 0.0) as usize);
    assert!(split.positions.len() > whole.positions.len() + 40, "the cut must split many vertices");
    (whole, split, original)
}

fn bent(points: &[Vec3]) -> Vec<Vec3> {
    points.iter().map(|p| *p + Vec3::new(0.0, 0.0, 0.6 * p.x * p.x + 0.2 * p.y)).collect()
}

fn bind(mesh: &PolyMesh) -> Sequence {
    Sequence::bind(mesh.input(), DeformerOptions::default()).unwrap()
}

fn assert_matches_whole(split_result: &[Vec3], whole_result: &[Vec3], original: &[usize]) {
    for (v, &o) in original.iter().enumerate() {
        let gap = (split_result[v] - whole_result[o]).length();
        assert!(gap <= 1e-6, "vertex {v} (a copy of {o}) is {gap} from the welded mesh's result");
    }
}

#[test]
fn a_split_mesh_deforms_exactly_like_the_welded_one() {
    let (whole, split, original) = split_sphere();
    let mut a = bind(&whole);
    let mut b = bind(&split);
    assert_eq!(b.vertex_count(), split.positions.len());
    assert_eq!(b.welded_vertex_count(), whole.positions.len());
    assert!(a.pinned().is_empty() && b.pinned().is_empty(), "a closed sphere needs no pins, split or not");

    let input_whole = bent(&whole.positions);
    let input_split = bent(&split.positions);
    let solved_whole = a.solve(&input_whole, 10, Closeness::Default).unwrap();
    let solved_split = b.solve(&input_split, 10, Closeness::Default).unwrap();
    assert_matches_whole(&solved_split, &solved_whole, &original);
    assert!((a.residual(&solved_whole).unwrap() - b.residual(&solved_split).unwrap()).abs() < 1e-6);

    let (stepped_whole, _) = a.step(&input_whole, &mut [], &StepOptions::default()).unwrap();
    let (stepped_split, _) = b.step(&input_split, &mut [], &StepOptions::default()).unwrap();
    assert_matches_whole(&stepped_split, &stepped_whole, &original);
    assert_eq!(b.history().unwrap().len(), split.positions.len());
}

#[test]
fn the_plain_mesh_is_not_welded() {
    // A cylinder's seam is already shared: nothing to weld, nothing copied.
    let tube = cylinder(16, 10, 0.2, 1.0);
    let sequence = bind(&tube);
    assert!(sequence.weld().is_identity());
    assert_eq!(sequence.welded_vertex_count(), tube.positions.len());
}

#[test]
fn painted_weights_are_gathered_per_seam_point() {
    let (whole, split, original) = split_sphere();
    let closeness_whole: Vec<f32> = whole.positions.iter().map(|p| 0.02 + 0.3 * (p.z * 0.5 + 0.5)).collect();
    let closeness_split: Vec<f32> = original.iter().map(|&o| closeness_whole[o]).collect();
    let stretch_whole: Vec<f32> = whole.positions.iter().map(|p| if p.x > 0.5 { 0.05 } else { f32::INFINITY }).collect();
    let stretch_split: Vec<f32> = original.iter().map(|&o| stretch_whole[o]).collect();
    let options = |closeness: &'static [f32], stretch: &'static [f32]| StepOptions {
        strain: Some(StrainOptions { max_stretch: MaxStretch::PerVertex(stretch), mode: StrainMode::Unified }),
        ..StepOptions::new(10, Closeness::PerVertex(closeness))
    };
    let leak = |v: Vec<f32>| -> &'static [f32] { Box::leak(v.into_boxed_slice()) };
    let input_whole: Vec<Vec3> = whole.positions.iter().map(|p| *p * Vec3::new(1.4, 1.0, 1.0)).collect();
    let input_split: Vec<Vec3> = split.positions.iter().map(|p| *p * Vec3::new(1.4, 1.0, 1.0)).collect();
    let (x_whole, report_whole) =
        bind(&whole).step(&input_whole, &mut [], &options(leak(closeness_whole), leak(stretch_whole))).unwrap();
    let (x_split, report_split) =
        bind(&split).step(&input_split, &mut [], &options(leak(closeness_split), leak(stretch_split))).unwrap();
    assert_matches_whole(&x_split, &x_whole, &original);
    assert!(report_whole.worst_stretch > 1.0 && (report_whole.worst_stretch - report_split.worst_stretch).abs() < 1e-6);
}

#[test]
fn per_vertex_arguments_are_checked_against_the_mesh_not_the_welded_vertices() {
    let (_, split, _) = split_sphere();
    let mut sequence = bind(&split);
    let n = split.positions.len();
    let short = vec![0.1f32; sequence.welded_vertex_count()];
    let error = sequence.solve(&split.positions, 1, Closeness::PerVertex(&short)).unwrap_err().to_string();
    assert!(error.contains(&format!("the mesh has {n} vertices")), "{error}");
    let mut bad = vec![0.1f32; n];
    bad[n - 1] = 2.0;
    let error = sequence.solve(&split.positions, 1, Closeness::PerVertex(&bad)).unwrap_err().to_string();
    assert!(error.contains(&format!("closeness of vertex {}", n - 1)), "{error}");
    let error = sequence.step(&split.positions[1..], &mut [], &StepOptions::default()).unwrap_err().to_string();
    assert!(error.contains(&format!("the deformer has {n}")), "{error}");
    assert!(sequence.set_history(&split.positions[1..]).is_err());
}

#[test]
fn a_collider_pressing_on_a_seam_neither_opens_it_nor_passes_through() {
    let (_, split, _) = split_sphere();
    let mut sequence = bind(&split);
    // A small sphere pushing into the skin at the seam point where all four shells meet (+z pole).
    let probe = quad_sphere(6, 0.3);
    let offsets: Vec<u32> = std::iter::once(0).chain((1..=probe.polygon_sizes.len()).map(|k| 4 * k as u32)).collect();
    let triangles = crate::mesh::fan_triangles(&probe.corner_verts, &offsets);
    let at = |z: f32| probe.positions.iter().map(|p| *p + Vec3::Z * z).collect::<Vec<_>>();
    let settings = ColliderSettings { thickness: 0.005, static_friction: 0.3, kinetic_friction: 0.2 };
    let mut collider = Collider::new(&at(1.6), &triangles, settings).unwrap();
    let top = (0..split.positions.len()).max_by(|&a, &b| split.positions[a].z.total_cmp(&split.positions[b].z)).unwrap();
    for z in [1.45, 1.3, 1.2, 1.2] {
        collider.update(&at(z)).unwrap();
        let (x, report) = sequence.step(&split.positions, &mut [&mut collider], &StepOptions::new(10, Closeness::Uniform(0.05))).unwrap();
        assert!(report.pinched.is_empty());
        let found = audit(MeshInput { positions: &x, ..split.input() }, &[&collider], &AuditParams::default()).unwrap();
        assert_eq!((found.vertices_inside.len(), found.edges_crossing.len(), found.collider_edges_crossing.len()), (0, 0, 0), "probe at {z}");
        let weld = sequence.weld();
        for v in 0..x.len() {
            let first = weld.members(weld.welded_of(v) as usize)[0] as usize;
            assert_eq!(x[v], x[first], "seam vertex {v} left its twin {first}");
        }
        // Where the probe reaches below the rest pole, the pole gives way to it.
        let pole = x[top].z;
        assert!(pole <= (z - 0.3 + 0.01).min(1.0 + 1e-5), "probe at {z}, pole at {pole}");
    }
}
