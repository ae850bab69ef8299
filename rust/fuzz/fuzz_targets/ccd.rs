//! Conservative CCD (vertex–triangle and edge–edge) on arbitrary motions.
//!
//! Never panics, always returns a time in [0, t_max] and parameters in
//! [0, 1]; and it is conservative: where a brute-force scan over a grid of
//! (t, u, v) finds the primitives clearly closer than the separation, CCD
//! must report a contact no later than that time.
#![no_main]

use glam::DVec3;
use libfuzzer_sys::arbitrary::{Result, Unstructured};
use libfuzzer_sys::fuzz_target;
use tegument_core::collide::ccd::{edge_edge, vertex_triangle, CcdParams};

fn coordinate(u: &mut Unstructured<'_>) -> Result<f64> {
    Ok(match u.int_in_range(0u8..=15)? {
        0 => f64::from_bits(u.arbitrary()?),
        1 => [f64::NAN, f64::INFINITY, 1e300, 1e-300, -0.0][u.choose_index(5)?],
        2 => u.int_in_range(-1000i32..=1000)? as f64 * 1e-3,
        _ => u.int_in_range(-8i8..=8)? as f64 * 0.25,
    })
}

fn point(u: &mut Unstructured<'_>) -> Result<DVec3> {
    Ok(DVec3::new(coordinate(u)?, coordinate(u)?, coordinate(u)?))
}

/// Distance vector of the query at `(t, u, v)`, the way the primitives move.
fn gap(edge: bool, p0: &[DVec3; 4], p1: &[DVec3; 4], t: f64, a: f64, b: f64) -> DVec3 {
    let q: Vec<DVec3> = (0..4).map(|k| p0[k].lerp(p1[k], t)).collect();
    let f = if edge {
        q[0].lerp(q[1], a) - q[2].lerp(q[3], b)
    } else {
        q[0] - (q[1] + a * (q[2] - q[1]) + b * (q[3] - q[1]))
    };
    f
}

fn run(u: &mut Unstructured<'_>) -> Result<()> {
    let edge = u.arbitrary::<bool>()?;
    let mut p0 = [DVec3::ZERO; 4];
    let mut p1 = [DVec3::ZERO; 4];
    for k in 0..4 {
        p0[k] = point(u)?;
        // Often a small move, so that contacts sit near the start and the end.
        p1[k] = if u.ratio(1u8, 2)? { p0[k] + point(u)? * 0.25 } else { point(u)? };
    }
    let params = CcdParams {
        min_separation: [0.0, 1e-3, 0.05, 0.25][u.choose_index(4)?],
        tolerance: [1e-6, 1e-4, 1e-9][u.choose_index(3)?],
        max_iterations: [100_000, 1_000, 1][u.choose_index(3)?],
        t_max: [1.0, 0.5, 0.0, -1.0, f64::NAN][u.choose_index(5)?],
    };
    let hit = if edge {
        edge_edge(p0[0], p0[1], p0[2], p0[3], p1[0], p1[1], p1[2], p1[3], &params)
    } else {
        vertex_triangle(p0[0], p0[1], p0[2], p0[3], p1[0], p1[1], p1[2], p1[3], &params)
    };
    let t_max = if params.t_max > 0.0 && params.t_max <= 1.0 { params.t_max } else { 1.0 };
    if let Some(hit) = hit {
        assert!((0.0..=t_max).contains(&hit.toi), "toi {} outside [0, {t_max}]", hit.toi);
        assert!((0.0..=1.0).contains(&hit.u) && (0.0..=1.0).contains(&hit.v), "{hit:?}");
        if !edge {
            assert!(hit.u + hit.v <= 1.0 + 1e-12, "{hit:?}");
        }
    }
    // Conservativeness, where a plain scan is meaningful (moderate, finite coordinates).
    let moderate = p0.iter().chain(p1.iter()).all(|p| p.is_finite() && p.abs().max_element() < 100.0);
    if !moderate {
        return Ok(());
    }
    const STEPS: usize = 24;
    let margin = 1e-6;
    'scan: for it in 0..=STEPS {
        let t = t_max * it as f64 / STEPS as f64;
        for ia in 0..=STEPS {
            for ib in 0..=STEPS {
                let (a, b) = (ia as f64 / STEPS as f64, ib as f64 / STEPS as f64);
                if !edge && a + b > 1.0 {
                    continue;
                }
                // With no separation only an exact touch is a contact (a length
                // would underflow to 0 for distances like 1e-300).
                let f = gap(edge, &p0, &p1, t, a, b);
                let touching = if params.min_separation == 0.0 { f == DVec3::ZERO } else { f.length() < params.min_separation - margin };
                if touching {
                    let hit = hit.unwrap_or_else(|| {
                        panic!("missed contact: edge={edge} t={t} a={a} b={b} p0={p0:?} p1={p1:?} {params:?}")
                    });
                    assert!(hit.toi <= t, "late contact: reported {} but in contact at {t}: {p0:?} {p1:?} {params:?}", hit.toi);
                    break 'scan;
                }
            }
        }
    }
    Ok(())
}

fuzz_target!(|data: &[u8]| {
    let _ = run(&mut Unstructured::new(data));
});
