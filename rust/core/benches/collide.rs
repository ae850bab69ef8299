//! Collision benchmark (issue 5): a ~100k-vertex skin (a 316² grid) against a
//! ~20k-triangle animated collider (a quad sphere that rises into the skin
//! and slides sideways). Measures the BVH build and refit, CCD throughput
//! (vertex–triangle and edge–edge queries per second), pass 1 (swept), the
//! in-loop pass, a whole frame's collision work (refit + pass 1 + 10 in-loop
//! passes between stand-in solver iterations), the audit, and the memory-
//! bandwidth reference in the same run.
//!
//! `cargo bench -p tegument-core --bench collide`

mod common;

use common::{bandwidth_reference_ms, machine, median_ms, with_threads, Report};
use glam::{DVec3, Vec3};
use tegument_core::collide::audit::audit;
use tegument_core::mesh::fan_triangles;
use tegument_core::collide::bvh::{BoxTree, Bounds};
use tegument_core::collide::ccd::{edge_edge, vertex_triangle, CcdParams};
use tegument_core::collide::{AuditParams, Clearance, Collider, ColliderSet, ColliderSettings, ResolveParams, Skin};
use tegument_core::mesh::shapes::{grid, quad_sphere, PolyMesh};

const ITERATIONS: usize = 10;
const FRAMES: usize = 7;
const RADIUS: f32 = 0.3;

/// Sphere centre at frame `k`: rises from below into the skin for 6 frames,
/// then slides along +x.
fn centre(k: usize) -> Vec3 {
    let k = k as f32;
    Vec3::new(-0.3 + 0.04 * (k - 6.0).max(0.0), 0.05, -RADIUS - 0.02 + 0.03 * k.min(6.0))
}

fn at(rest: &[Vec3], c: Vec3) -> Vec<Vec3> {
    rest.iter().map(|&p| p + c).collect()
}

struct Scene {
    skin: PolyMesh,
    topology: Skin,
    sphere_rest: Vec<Vec3>,
    collider: Collider,
    /// Last frame's collision-free output.
    output: Vec<Vec3>,
}

/// One frame of collision work, as `Sequence::step` does it (the
/// clearance and planes measured once, at the start of the in-loop passes). The solver
/// iteration is a stand-in: it pulls the skin halfway back to the flat input.
fn frame(scene: &mut Scene, k: usize) -> (usize, usize) {
    scene.collider.update(&at(&scene.sphere_rest, centre(k))).unwrap();
    let set = ColliderSet::new([&scene.collider]);
    let input = &scene.skin.positions;
    let mut x = input.clone();
    let first = set.resolve_path(&scene.output, &mut x, &scene.topology, &ResolveParams::first_pass()).unwrap();
    let mut pinched = first.pinched.len();
    let mut before = x.clone();
    let colliders = [&scene.collider];
    let clearance = Clearance::new(&colliders, &scene.topology, &x, Clearance::default_radius(&colliders, &scene.topology, &x)).unwrap().with_planes(&colliders).unwrap();
    for _ in 0..ITERATIONS {
        before.copy_from_slice(&x);
        for (p, q) in x.iter_mut().zip(input) {
            *p += 0.5 * (*q - *p);
        }
        let s = set.resolve_path_with(&before, &mut x, &scene.topology, &ResolveParams::in_loop(), Some(&clearance), None).unwrap();
        pinched = s.pinched.len();
    }
    scene.output = x;
    (first.moved.len(), pinched)
}

fn lcg(seed: &mut u64) -> f64 {
    *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

fn random_point(seed: &mut u64) -> DVec3 {
    DVec3::new(lcg(seed), lcg(seed), lcg(seed))
}

fn main() {
    let mut report = Report::new("collide");
    report.add("machine", &machine(), 0.0, "", 0, "");

    let skin = grid(316, 316, 2.0);
    let topology = Skin::from_mesh(skin.input()).unwrap();
    let sphere = quad_sphere(41, RADIUS);
    let sphere_tris = fan_triangles(&sphere.corner_verts, &sphere.input().validate().unwrap());
    let case = format!(
        "skin {} v / {} tri vs collider {} tri",
        skin.positions.len(),
        topology.triangles().len(),
        sphere_tris.len()
    );
    println!("{case}");
    let settings = ColliderSettings { thickness: 0.005, static_friction: 0.4, kinetic_friction: 0.3 };

    // BVH build and refit over the collider's swept triangle boxes.
    let c0 = Collider::new(&at(&sphere.positions, centre(0)), &sphere_tris, settings).unwrap();
    let boxes: Vec<Bounds> = (0..sphere_tris.len()).map(|t| c0.swept_box(t)).collect();
    for threads in [1usize, 2] {
        let build = with_threads(threads, || median_ms(9, || drop(BoxTree::build(&boxes).unwrap())));
        report.add(&case, "BVH build (PLOC, fast preset)", build, "ms", threads, &format!("{} boxes", boxes.len()));
        let mut c = c0.clone();
        let (a, b) = (at(&sphere.positions, centre(6)), at(&sphere.positions, centre(7)));
        let mut flip = false;
        let refit = with_threads(threads, || {
            median_ms(15, || {
                flip = !flip;
                c.update(if flip { &a } else { &b }).unwrap();
            })
        });
        report.add(&case, "collider update (refit both BVHs)", refit, "ms", threads, &format!("cost ratio {:.3}", c.tree().cost_ratio()));
    }

    // CCD throughput on random queries in the unit cube (mixed hits/misses).
    let mut seed = 7u64;
    let queries: Vec<[DVec3; 8]> = (0..20_000).map(|_| std::array::from_fn(|_| random_point(&mut seed))).collect();
    let params = CcdParams::default();
    let mut hits = 0usize;
    let vf = median_ms(5, || {
        hits = queries.iter().filter(|q| vertex_triangle(q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7], &params).is_some()).count();
    });
    report.add("CCD, random unit-cube queries", "vertex-triangle", queries.len() as f64 / vf * 1e3, "q/s", 1, &format!("{:.0}% hit, {:.2} µs/query", 100.0 * hits as f64 / queries.len() as f64, vf * 1e3 / queries.len() as f64));
    let ee = median_ms(5, || {
        hits = queries.iter().filter(|q| edge_edge(q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7], &params).is_some()).count();
    });
    report.add("CCD, random unit-cube queries", "edge-edge", queries.len() as f64 / ee * 1e3, "q/s", 1, &format!("{:.0}% hit, {:.2} µs/query", 100.0 * hits as f64 / queries.len() as f64, ee * 1e3 / queries.len() as f64));

    // The animated scene: run the frames once to reach the sliding phase.
    let mut scene = Scene {
        topology,
        sphere_rest: sphere.positions.clone(),
        collider: c0.clone(),
        output: skin.positions.clone(),
        skin,
    };
    scene.collider.hold().unwrap();
    let mut moved = 0;
    for k in 1..FRAMES {
        let t = std::time::Instant::now();
        let (m, p) = frame(&mut scene, k);
        moved = m;
        println!(
            "frame {k}: {m} vertices moved by pass 1, {p} pinched after the last in-loop pass, {:.0} ms",
            t.elapsed().as_secs_f64() * 1e3
        );
    }
    let input_audit = audit(scene.skin.input(), &[&scene.collider], &AuditParams::default()).unwrap();
    let output_mesh = PolyMesh { positions: scene.output.clone(), ..scene.skin.clone() };
    let output_audit = audit(output_mesh.input(), &[&scene.collider], &AuditParams::default()).unwrap();
    report.add(&case, "audit of the input: vertices inside", input_audit.vertices_inside.len() as f64, "", 0, "");
    report.add(&case, "audit of the output: vertices inside", output_audit.vertices_inside.len() as f64, "", 0, "");
    report.add(&case, "audit of the output: edges crossing", output_audit.edges_crossing.len() as f64, "", 0, "");
    report.add(&case, "audit of the output: collider edges crossing", output_audit.collider_edges_crossing.len() as f64, "", 0, "");
    report.add(&case, "vertices moved by pass 1 (last frame)", moved as f64, "", 0, "");

    let n = scene.skin.positions.len();
    let read = n * 12 * 2 + scene.collider.vertex_count() * 12 * 2;
    let write = n * 12;
    // Whole frames are slow (see docs/performance.md): one timed run, 2 threads.
    {
        let threads = 2usize;
        let state = (scene.collider.clone(), scene.output.clone());
        let k = FRAMES;
        let whole = with_threads(threads, || {
            median_ms(1, || {
                scene.collider = state.0.clone();
                scene.output = state.1.clone();
                frame(&mut scene, k);
            })
        });
        report.add(&case, &format!("frame: refit + pass 1 + {ITERATIONS} in-loop passes"), whole, "ms", threads, "stand-in solver step, not the pyramid solve");
        // The parts.
        scene.collider = state.0.clone();
        scene.output = state.1.clone();
        scene.collider.update(&at(&scene.sphere_rest, centre(k))).unwrap();
        let set = ColliderSet::new([&scene.collider]);
        let mut x = scene.skin.positions.clone();
        let pass1 = with_threads(threads, || {
            median_ms(1, || {
                x.copy_from_slice(&scene.skin.positions);
                set.resolve_path(&scene.output, &mut x, &scene.topology, &ResolveParams::first_pass()).unwrap();
            })
        });
        report.add(&case, "pass 1 (swept collider)", pass1, "ms", threads, "");
        let before = x.clone();
        let pulled: Vec<Vec3> = before.iter().zip(&scene.skin.positions).map(|(p, q)| *p + 0.5 * (*q - *p)).collect();
        let radius = Clearance::default_radius(&[&scene.collider], &scene.topology, &before);
        let mut clearance = None;
        let measure = with_threads(threads, || {
            median_ms(3, || clearance = Some(Clearance::new(&[&scene.collider], &scene.topology, &before, radius).unwrap().with_planes(&[&scene.collider]).unwrap()))
        });
        let planes = clearance.as_ref().and_then(|c| c.planes()).map_or(0, |p| p.vertex_count());
        report.add(&case, "clearance and planes (once per frame)", measure, "ms", threads, &format!("radius {radius:.4}, planes around {planes} vertices"));
        let mut y = pulled.clone();
        let in_loop = with_threads(threads, || {
            median_ms(3, || {
                y.copy_from_slice(&pulled);
                set.resolve_path_with(&before, &mut y, &scene.topology, &ResolveParams::in_loop(), clearance.as_ref(), None).unwrap();
            })
        });
        report.add(&case, "one in-loop pass", in_loop, "ms", threads, "with the clearance and planes");
        let in_loop_alone = with_threads(threads, || {
            median_ms(3, || {
                y.copy_from_slice(&pulled);
                set.resolve_path(&before, &mut y, &scene.topology, &ResolveParams::in_loop()).unwrap();
            })
        });
        report.add(&case, "one in-loop pass without a clearance", in_loop_alone, "ms", threads, "every element looked up");
        let audit_ms = with_threads(threads, || {
            median_ms(3, || {
                audit(output_mesh.input(), &[&scene.collider], &AuditParams::default()).unwrap();
            })
        });
        report.add(&case, "audit", audit_ms, "ms", threads, "");
        let reference = bandwidth_reference_ms(read, write, threads);
        report.add(&case, "bandwidth reference", reference, "ms", threads, &format!("{:.1} MB read + {:.1} MB written", read as f64 / 1e6, write as f64 / 1e6));
        report.add(&case, "in-loop pass / reference", in_loop / reference, "x", threads, "");
        drop(set);
        scene.collider = state.0;
        scene.output = state.1;
    }
    report.save();
}
