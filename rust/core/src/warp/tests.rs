//! The "must show" tests of the UV warp.

use glam::{Vec2, Vec3};

use super::fixtures::{bend, rectangles, uv_cylinder, UvPolyMesh};
use super::*;

const N: usize = 128;

fn cylinder() -> UvPolyMesh {
    uv_cylinder(64, 32, 1.0, std::f32::consts::TAU, 0.1)
}

/// Bent so that the +X side squashes to half and the −X side stretches to 1.5.
fn bent(m: &UvPolyMesh, amount: f32) -> Vec<Vec3> {
    bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * amount)
}

/// Rigid squares on the squashed side (+X: u = 0.7) and the stretched side (−X: u = 0.3).
fn squares() -> Vec<f32> {
    let s = 0.06;
    rectangles(N, N, &[(0.7 - s, 0.5 - s, 0.7 + s, 0.5 + s), (0.3 - s, 0.5 - s, 0.3 + s, 0.5 + s)])
}

fn settings(warm: bool) -> WarpSettings {
    WarpSettings { iterations: 8, warm_start: warm, ..Default::default() }
}

fn cylinder_warp(warm: bool) -> (UvPolyMesh, UvWarp) {
    let m = cylinder();
    let r = squares();
    let warp = UvWarp::new(m.input(), &m.corner_uvs, N, N, &[TileMaps { udim: 1001, rigidity: &r, mask: None }], settings(warm)).unwrap();
    (m, warp)
}

#[test]
fn rest_equals_deformed_gives_the_identity() {
    let (m, mut warp) = cylinder_warp(false);
    warp.solve(&m.positions).unwrap();
    let met = &warp.metrics(&m.positions).unwrap()[0];
    assert!(met.max_displacement < 0.01, "{met:?}");
    assert!(met.round_trip_max < 0.01, "{met:?}");
    // The redirection is the identity too.
    let tile = &warp.tiles[0];
    for (i, uv) in tile.redirection.chunks(2).enumerate() {
        let (x, y) = (i % N, i / N);
        assert!((uv[0] - (x as f32 + 0.5) / N as f32).abs() < 1e-5 && (uv[1] - (y as f32 + 0.5) / N as f32).abs() < 1e-5);
    }
}

#[test]
fn bent_cylinder_rigid_squares_keep_their_size() {
    let (m, mut warp) = cylinder_warp(false);
    let def = bent(&m, 1.0);
    warp.solve(&def).unwrap();
    let met = &warp.metrics(&def).unwrap()[0];
    eprintln!("{met:#?}");
    assert!(met.rigid_texels > 400, "{met:?}");
    assert!(met.stretch_identity.mean > 0.3, "the fixture must actually distort the squares: {met:?}");
    assert!(
        met.stretch_warped.mean * 3.0 <= met.stretch_identity.mean,
        "mean rigid stretch error {} is not 3× below the identity's {}",
        met.stretch_warped.mean,
        met.stretch_identity.mean
    );
    assert!(met.stretch_warped.p95 < met.stretch_identity.p95 / 2.0, "{met:?}");
    // Masked texels never move, no fold-overs, round trip below half a texel.
    assert_eq!(met.max_masked_displacement, 0.0);
    assert_eq!(met.foldovers, 0);
    assert!(met.round_trip_max < 0.5, "{met:?}");
    assert!(met.max_displacement > 2.0, "the warp must actually move texels: {met:?}");
}

#[test]
fn user_mask_fixes_texels() {
    let m = cylinder();
    let r = squares();
    // Fix a band through the squashed square's neighbourhood.
    let mut mask = vec![1.0f32; N * N];
    for y in 0..N {
        for x in 80..84 {
            mask[y * N + x] = 0.0;
        }
    }
    let mut warp = UvWarp::new(m.input(), &m.corner_uvs, N, N, &[TileMaps { udim: 1001, rigidity: &r, mask: Some(&mask) }], settings(false)).unwrap();
    let def = bent(&m, 1.0);
    warp.solve(&def).unwrap();
    let (dx, dy) = warp.tiles[0].displacement();
    for y in 0..N {
        for x in 80..84 {
            assert_eq!((dx[y * N + x], dy[y * N + x]), (0.0, 0.0), "texel ({x}, {y}) is masked but moved");
        }
    }
    // Outside charts and on chart borders nothing moves either.
    let layout = &warp.tiles[0].layout;
    for i in 0..N * N {
        if layout.interior[i] == 0 {
            assert_eq!((dx[i], dy[i]), (0.0, 0.0), "texel {i} is outside the chart interior but moved");
        }
    }
    assert!(dx.iter().any(|&d| d.abs() > 1.0), "the rest of the grid still warps");
}

#[test]
fn temporal_coherence_small_change_small_warp_change() {
    let (m, mut warp) = cylinder_warp(true);
    // Converge at the first pose.
    for _ in 0..6 {
        warp.solve(&bent(&m, 1.0)).unwrap();
    }
    let snap = |w: &UvWarp| {
        let (dx, dy) = w.tiles[0].displacement();
        (dx.to_vec(), dy.to_vec())
    };
    let max_diff = |a: &(Vec<f32>, Vec<f32>), b: &(Vec<f32>, Vec<f32>)| {
        a.0.iter().zip(&b.0).chain(a.1.iter().zip(&b.1)).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max)
    };
    let base = snap(&warp);
    let total = base.0.iter().zip(&base.1).map(|(x, y)| (x * x + y * y).sqrt()).fold(0.0f32, f32::max);
    // Same pose again: the warm start barely moves.
    warp.solve(&bent(&m, 1.0)).unwrap();
    let still = max_diff(&base, &snap(&warp));
    // 1% more bend.
    let mut w1 = warp.clone();
    w1.solve(&bent(&m, 1.01)).unwrap();
    let d1 = max_diff(&snap(&warp), &snap(&w1));
    // 4% more bend.
    let mut w4 = warp.clone();
    w4.solve(&bent(&m, 1.04)).unwrap();
    let d4 = max_diff(&snap(&warp), &snap(&w4));
    eprintln!("total {total} still {still} d1 {d1} d4 {d4}");
    assert!(total > 2.0);
    assert!(still < 0.05 * total, "same pose moved the warp by {still} texels (warp size {total})");
    // A 1% change of the bend changes the warp by a bounded multiple of 1% of its size.
    assert!(d1 < 0.5 && d1 < 5.0 * 0.01 * total, "1% more bend moved the warp by {d1} texels (warp size {total})");
    assert!(d4 < 5.0 * 0.04 * total, "4% more bend moved the warp by {d4} texels (warp size {total})");
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let (m, warp) = cylinder_warp(true);
    let run = |threads: usize| {
        let mut w = warp.clone();
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
            w.solve(&bent(&m, 0.8)).unwrap();
            w.solve(&bent(&m, 1.0)).unwrap();
        });
        let t = &w.tiles[0];
        (t.displacement().0.to_vec(), t.displacement().1.to_vec(), t.redirection.clone())
    };
    let one = run(1);
    for threads in [2, 3, 7] {
        let other = run(threads);
        assert!(one.0.iter().zip(&other.0).all(|(a, b)| a.to_bits() == b.to_bits()), "dx differs with {threads} threads");
        assert!(one.1.iter().zip(&other.1).all(|(a, b)| a.to_bits() == b.to_bits()), "dy differs with {threads} threads");
        assert!(one.2.iter().zip(&other.2).all(|(a, b)| a.to_bits() == b.to_bits()), "redirection differs with {threads} threads");
    }
}

#[test]
fn reset_gives_the_same_result_as_a_fresh_cold_solve() {
    let (m, mut warp) = cylinder_warp(true);
    let fresh = {
        let (_, mut w) = cylinder_warp(true);
        w.solve(&bent(&m, 1.0)).unwrap();
        w.tiles[0].redirection.clone()
    };
    warp.solve(&bent(&m, 0.5)).unwrap();
    warp.reset();
    warp.solve(&bent(&m, 1.0)).unwrap();
    assert_eq!(warp.tiles[0].redirection, fresh);
}

#[test]
fn layout_is_watertight_and_finds_the_chart() {
    let (_, warp) = cylinder_warp(false);
    let l = &warp.tiles[0].layout;
    assert_eq!(l.overlaps, 0);
    assert_eq!(warp.mesh.chart_count, 1);
    // Every texel centre strictly inside the chart [0.1, 0.9]² is covered once.
    for y in 0..N {
        for x in 0..N {
            let (u, v) = ((x as f32 + 0.5) / N as f32, (y as f32 + 0.5) / N as f32);
            let inside = u > 0.1 && u < 0.9 && v > 0.1 && v < 0.9;
            let outside = !(0.1..=0.9).contains(&u) || !(0.1..=0.9).contains(&v);
            if inside {
                assert_eq!(l.covered[y * N + x], 1, "({x}, {y})");
            }
            if outside {
                assert_eq!(l.covered[y * N + x], 0, "({x}, {y})");
            }
        }
    }
    // Interpolated rest positions lie on the cylinder, also a few texels past the border.
    let m = cylinder();
    let fo = l.interpolate(&warp.mesh, &m.positions);
    let mut outside_but_extended = 0;
    for (i, p) in fo.iter().enumerate() {
        if let Some(p) = p {
            let r = (p.x * p.x + p.y * p.y).sqrt();
            // On the surface inside (chords of 64 segments), linearly
            // extrapolated along the tangent plane outside.
            let tol = if l.covered[i] == 1 { 0.002 } else { 0.05 };
            assert!((r - 1.0).abs() < tol, "texel {i}: radius {r}");
            outside_but_extended += (l.covered[i] == 0) as usize;
        }
    }
    assert!(outside_but_extended > 0);
}

#[test]
fn bad_input_is_refused_with_a_message() {
    let m = cylinder();
    let r = squares();
    let make = |w: usize, h: usize, uvs: &[Vec2], maps: &[TileMaps<'_>]| UvWarp::new(m.input(), uvs, w, h, maps, settings(false)).map(|_| ()).unwrap_err().to_string();
    let ok = [TileMaps { udim: 1001, rigidity: &r, mask: None }];
    assert!(make(100, 128, &m.corner_uvs, &ok).contains("power of two"));
    assert!(make(N, N, &m.corner_uvs[1..], &ok).contains("corner_uvs has"));
    let mut nan = m.corner_uvs.clone();
    nan[7] = Vec2::new(f32::NAN, 0.0);
    assert!(make(N, N, &nan, &ok).contains("corner 7"));
    let short = vec![0.0; 10];
    assert!(make(N, N, &m.corner_uvs, &[TileMaps { udim: 1001, rigidity: &short, mask: None }]).contains("shape (height=128, width=128)"));
    let mut bad = r.clone();
    bad[3 * N + 5] = f32::NAN;
    assert!(make(N, N, &m.corner_uvs, &[TileMaps { udim: 1001, rigidity: &bad, mask: None }]).contains("(row 3, column 5)"));
    assert!(make(N, N, &m.corner_uvs, &[]).contains("no rigidity map was given for it"));
    let err = UvWarp::new(m.input(), &m.corner_uvs, 16384, 16384, &ok, settings(false)).unwrap_err().to_string();
    assert!(err.contains("16384×16384") && err.contains("GiB"), "{err}");
    let (_, mut warp) = cylinder_warp(false);
    let err = warp.solve(&m.positions[1..]).unwrap_err().to_string();
    assert!(err.contains("deformed positions has"), "{err}");
    let mut p = m.positions.clone();
    p[3].y = f32::INFINITY;
    assert!(warp.solve(&p).unwrap_err().to_string().contains("vertex 3"));
}

#[test]
fn udim_tiles_get_their_own_grids() {
    let mut m = cylinder();
    // Move the upper half of the polygons' UVs to tile 1002 (u + 1).
    let quads = m.polygon_sizes.len();
    for q in quads / 2..quads {
        for c in 4 * q..4 * q + 4 {
            m.corner_uvs[c].x += 1.0;
        }
    }
    // Without a rigidity map for each tile the UVs touch, the error names the tile.
    let missing = UvWarp::new(m.input(), &m.corner_uvs, 64, 64, &[], settings(false)).map(|_| ()).unwrap_err();
    assert!(missing.to_string().contains("1001"), "{missing}");
    let r64 = rectangles(64, 64, &[(0.6, 0.6, 0.8, 0.8)]);
    let maps64 = [TileMaps { udim: 1001, rigidity: &r64, mask: None }, TileMaps { udim: 1002, rigidity: &r64, mask: None }];
    let mut w = UvWarp::new(m.input(), &m.corner_uvs, 64, 64, &maps64, settings(false)).unwrap();
    assert_eq!(w.tiles.iter().map(|t| t.udim()).collect::<Vec<_>>(), vec![1001, 1002]);
    w.solve(&bent(&m, 1.0)).unwrap();
    let t2 = w.tile(1002).unwrap();
    assert!(t2.redirection.chunks(2).all(|uv| uv[0] >= 1.0 && uv[0] <= 2.0), "tile 1002 redirects into its own tile");
    for met in w.metrics(&bent(&m, 1.0)).unwrap() {
        assert_eq!(met.foldovers, 0);
        assert_eq!(met.max_masked_displacement, 0.0);
    }
}

#[test]
fn exr_round_trip_keeps_values_rows_and_metadata() {
    let (m, mut warp) = cylinder_warp(false);
    warp.solve(&bent(&m, 1.0)).unwrap();
    let dir = std::env::temp_dir().join(format!("tegument-warp-exr-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("warp.1001.exr");
    warp.write_exr(1001, &path).unwrap();
    let (w, h, c, data, meta) = super::exr::read_exr(&path).unwrap();
    assert_eq!((w, h, c), (N, N, 3));
    let t = &warp.tiles[0];
    for i in 0..N * N {
        assert_eq!(data[3 * i], t.redirection[2 * i]);
        assert_eq!(data[3 * i + 1], t.redirection[2 * i + 1]);
        assert_eq!(data[3 * i + 2], t.layout.covered[i] as f32);
    }
    assert!(meta.contains(&("iterations".to_string(), warp.settings.iterations.to_string())), "{meta:?}");
    assert!(meta.iter().any(|(k, _)| k == "smoothing"));
    // No temporary file left behind; NaN refused without touching the old file.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    let before = std::fs::read(&path).unwrap();
    let err = super::exr::write_exr(&path, 2, 1, 2, &[0.0, 1.0, f32::NAN, 0.0], &[]).unwrap_err();
    assert!(err.to_string().contains("row 0, column 1"), "{err}");
    assert_eq!(std::fs::read(&path).unwrap(), before);
    std::fs::remove_dir_all(&dir).unwrap();
}

// ---- Spot -----------------------------------------------------------------

/// Spot's folder; panics, naming it, if it is incomplete. A test calling this
/// is ignored where the data folder is absent (see `rust/core/build.rs`).
fn spot_dir() -> std::path::PathBuf {
    let root = match std::env::var_os("TEGUMENT_DATA_DIR") {
        Some(dir) => std::path::PathBuf::from(dir),
        None => std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    };
    let dir = root.join("meshes/spot");
    assert!(
        dir.join("spot_triangulated.obj").exists() && dir.join("spot_texture.png").exists(),
        "Spot test data not found at {} (../shared/data relative to the project root, or $TEGUMENT_DATA_DIR)",
        dir.display()
    );
    dir
}

/// Minimal OBJ reader: `v`, `vt`, `f` with `v/vt[/vn]` corners.
fn read_obj(path: &std::path::Path) -> UvPolyMesh {
    let text = std::fs::read_to_string(path).unwrap();
    let mut m = UvPolyMesh::default();
    let mut vts = Vec::new();
    let mut faces: Vec<Vec<(usize, usize)>> = Vec::new();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let v: Vec<f32> = it.take(3).map(|s| s.parse().unwrap()).collect();
                m.positions.push(Vec3::new(v[0], v[1], v[2]));
            }
            Some("vt") => {
                let v: Vec<f32> = it.take(2).map(|s| s.parse().unwrap()).collect();
                vts.push(Vec2::new(v[0], v[1]));
            }
            Some("f") => faces.push(
                it.map(|c| {
                    let mut p = c.split('/');
                    (p.next().unwrap().parse::<usize>().unwrap() - 1, p.next().unwrap().parse::<usize>().unwrap() - 1)
                })
                .collect(),
            ),
            _ => {}
        }
    }
    for f in faces {
        m.polygon_sizes.push(f.len() as i32);
        for (v, t) in f {
            m.corner_verts.push(v as i32);
            m.corner_uvs.push(vts[t]);
        }
    }
    m
}

/// Minimal PNG reader (8-bit RGB/RGBA, non-interlaced) → (width, height, channels, top row first).
fn read_png(path: &std::path::Path) -> (usize, usize, usize, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let (mut w, mut h, mut ch) = (0, 0, 0);
    let mut idat = Vec::new();
    let mut at = 8;
    while at + 8 <= bytes.len() {
        let len = u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        let kind = &bytes[at + 4..at + 8];
        let body = &bytes[at + 8..at + 8 + len];
        match kind {
            b"IHDR" => {
                w = u32::from_be_bytes(body[0..4].try_into().unwrap()) as usize;
                h = u32::from_be_bytes(body[4..8].try_into().unwrap()) as usize;
                assert_eq!(body[8], 8, "8-bit only");
                ch = match body[9] {
                    2 => 3,
                    6 => 4,
                    t => panic!("colour type {t}"),
                };
                assert_eq!(body[12], 0, "non-interlaced only");
            }
            b"IDAT" => idat.extend_from_slice(body),
            _ => {}
        }
        at += 12 + len;
    }
    let raw = miniz_oxide::inflate::decompress_to_vec_zlib(&idat).unwrap();
    let stride = w * ch;
    let mut out = vec![0u8; h * stride];
    for y in 0..h {
        let filter = raw[y * (stride + 1)];
        let line = &raw[y * (stride + 1) + 1..(y + 1) * (stride + 1)];
        for x in 0..stride {
            let a = if x >= ch { out[y * stride + x - ch] as i32 } else { 0 };
            let b = if y > 0 { out[(y - 1) * stride + x] as i32 } else { 0 };
            let c = if x >= ch && y > 0 { out[(y - 1) * stride + x - ch] as i32 } else { 0 };
            let pred = match filter {
                0 => 0,
                1 => a,
                2 => b,
                3 => (a + b) / 2,
                4 => {
                    let p = a + b - c;
                    let (pa, pb, pc) = ((p - a).abs(), (p - b).abs(), (p - c).abs());
                    if pa <= pb && pa <= pc {
                        a
                    } else if pb <= pc {
                        b
                    } else {
                        c
                    }
                }
                f => panic!("filter {f}"),
            };
            out[y * stride + x] = (line[x] as i32 + pred) as u8;
        }
    }
    (w, h, ch, out)
}

/// Rigidity from Spot's texture: texels whose colour is far from the skin
/// colour (the spots, eyes, nostrils, hooves) are rigid. Box-filtered to the
/// grid; row 0 = lowest v (the PNG's bottom row).
pub(super) fn spot_rigidity(dir: &std::path::Path, n: usize) -> Vec<f32> {
    let (w, h, ch, px) = read_png(&dir.join("spot_texture.png"));
    let skin = [255.0, 236.0, 228.0];
    let mut r = vec![0.0f32; n * n];
    let (fx, fy) = (w / n, h / n);
    for y in 0..n {
        for x in 0..n {
            let mut acc = 0.0;
            for yy in 0..fy {
                for xx in 0..fx {
                    let py = h - 1 - (y * fy + yy);
                    let p = &px[(py * w + x * fx + xx) * ch..];
                    let d = ((p[0] as f32 - skin[0]).powi(2) + (p[1] as f32 - skin[1]).powi(2) + (p[2] as f32 - skin[2]).powi(2)).sqrt();
                    acc += if d > 60.0 { 1.0 } else { 0.0 };
                }
            }
            r[y * n + x] = acc / (fx * fy) as f32;
        }
    }
    r
}

#[test]
#[cfg_attr(not(any(shared_data, require_shared_data)), ignore = "../shared/data is absent: the shared test data sits beside the checkout (or set $TEGUMENT_DATA_DIR)")]
fn spot_under_a_bend_rigidity_from_its_texture() {
    let dir = spot_dir();
    let m = read_obj(&dir.join("spot_triangulated.obj"));
    let n = 256;
    let r = spot_rigidity(&dir, n);
    let rigid = r.iter().filter(|&&v| v >= 0.5).count();
    assert!(rigid > n * n / 20, "the feature mask should cover a good part of the texture ({rigid} texels)");
    let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &r, mask: None }], settings(false)).unwrap();
    assert_eq!(warp.mesh.chart_count, 13, "Spot has 13 UV charts");
    assert_eq!(warp.tiles.len(), 1);
    // Bend the body (long axis z) around x; the back (y = 0.8) stretches by 1.4, the belly (y = -0.5) squashes.
    let def = bend(&m.positions, 2, 1, 0.0, -0.7, 0.5);
    warp.solve(&def).unwrap();
    let met = &warp.metrics(&def).unwrap()[0];
    eprintln!("{met:#?}");
    assert!(met.stretch_identity.mean > 0.05, "the bend must distort features: {met:?}");
    assert!(met.stretch_warped.mean < 0.9 * met.stretch_identity.mean, "rigid stretch error not reduced: {met:?}");
    assert!(met.stretch_warped.p95 < met.stretch_identity.p95, "{met:?}");
    assert_eq!(met.foldovers, 0, "{met:?}");
    assert_eq!(met.max_masked_displacement, 0.0, "chart borders must stay fixed");
    assert!(met.round_trip_max < 0.5, "{met:?}");
}

#[test]
fn gathered_inversion_matches_the_rasterised_reference() {
    // Cold and warm warps of the bent cylinder, plus a strongly swirled synthetic warp.
    let (m, mut warp) = cylinder_warp(false);
    let mut cases = Vec::new();
    warp.solve(&bent(&m, 1.0)).unwrap();
    let (dx, dy) = warp.tiles[0].displacement();
    cases.push((dx.to_vec(), dy.to_vec()));
    let (mut sx, mut sy) = (vec![0.0f32; N * N], vec![0.0f32; N * N]);
    for j in 1..N - 1 {
        for i in 1..N - 1 {
            let (u, v) = (i as f32 / N as f32 - 0.5, j as f32 / N as f32 - 0.5);
            let fall = (1.0 - 4.0 * (u * u + v * v)).max(0.0).powi(2);
            let a = 0.8 * fall;
            sx[j * N + i] = N as f32 * (u * a.cos() - v * a.sin() - u);
            sy[j * N + i] = N as f32 * (u * a.sin() + v * a.cos() - v);
        }
    }
    assert_eq!(solver::count_folds(&sx, &sy, N, N, 0.0), 0);
    cases.push((sx, sy));
    for (dx, dy) in cases {
        let mut a = vec![0.0; 2 * N * N];
        let mut b = vec![0.0; 2 * N * N];
        invert::invert(&dx, &dy, N, N, Vec2::new(1.0, 0.0), &mut a);
        invert::invert_scatter(&dx, &dy, N, N, Vec2::new(1.0, 0.0), &mut b);
        let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max) * N as f32;
        assert!(worst < 1e-3, "gather and scatter differ by {worst} texel");
    }
}

/// Where the warp's compression changes quickly, the walk's first (Newton)
/// step overshoots: from a cell squeezed to a tenth, the extended map of a
/// texel lying past the squeezed band in a stretched one points some 100
/// cells too far, more than the walk has steps. (At 4096² in the benchmark
/// 30 texels ended 250 texels off this way.) Such walks are taken again
/// cell by cell; the gather must still equal the rasterised inversion.
#[test]
fn an_overshooting_first_step_still_finds_the_triangle() {
    let (w, h) = (16usize, 512usize);
    // Warped node rows Y(j): spacing 1 up to row 100, 0.1 up to 200, 1.8 up
    // to 300, then even to the fixed last row.
    let mut rows = vec![0.0f64; h];
    for j in 1..h {
        let spacing = match j - 1 {
            0..=99 => 1.0,
            100..=199 => 0.1,
            200..=299 => 1.8,
            _ => (h as f64 - 1.0 - 290.0) / (h as f64 - 1.0 - 300.0),
        };
        rows[j] = rows[j - 1] + spacing;
    }
    assert!((rows[h - 1] - (h - 1) as f64).abs() < 1e-9);
    let dx = vec![0.0f32; w * h];
    let dy: Vec<f32> = (0..w * h).map(|n| (rows[n / w] - (n / w) as f64) as f32).collect();
    assert_eq!(solver::count_folds(&dx, &dy, w, h, 0.0), 0);
    let overshooting = (0..h).filter(|&y| invert::walk(&dx, &dy, w, h, w / 2, y).1 > 48).count();
    assert!(overshooting > 0, "the fixture must make some first steps overshoot");
    let (mut a, mut b) = (vec![0.0; 2 * w * h], vec![0.0; 2 * w * h]);
    invert::invert(&dx, &dy, w, h, Vec2::ZERO, &mut a);
    invert::invert_scatter(&dx, &dy, w, h, Vec2::ZERO, &mut b);
    // The border columns move here (a solved warp keeps them fixed), so
    // their centres lie on the warped grid's outline, where the rasterised
    // reference leaves the identity: compare the columns inside.
    let texel = |r: &[f32], x: usize, y: usize| (r[2 * (y * w + x)] * w as f32, r[2 * (y * w + x) + 1] * h as f32);
    let worst = (0..h).flat_map(|y| (1..w - 1).map(move |x| (x, y))).map(|(x, y)| {
        let (p, q) = (texel(&a, x, y), texel(&b, x, y));
        (p.0 - q.0).abs().max((p.1 - q.1).abs())
    });
    let worst = worst.fold(0.0f32, f32::max);
    assert!(worst < 1e-3, "gather and scatter differ by {worst} texel ({overshooting} rows needed the second walk)");
}

/// The lane-wise inversion gives every texel exactly the per-texel walk's
/// result: on solved warps, on a swirl strong enough that many texels need the
/// second round or the one-by-one walk, and on a width that leaves a tail.
/// (The walk lengths counted are those from the texel's own displacement,
/// where the first two rows of every band start.)
#[test]
fn lane_wise_inversion_equals_the_per_texel_walk_to_the_bit() {
    let (m, mut warp) = cylinder_warp(false);
    warp.solve(&bent(&m, 1.0)).unwrap();
    let (dx, dy) = warp.tiles[0].displacement();
    let mut cases = vec![(dx.to_vec(), dy.to_vec(), N, N)];
    for (w, h, strength) in [(N, N, 2.5f32), (77, 45, 1.5)] {
        let (mut sx, mut sy) = (vec![0.0f32; w * h], vec![0.0f32; w * h]);
        for j in 1..h - 1 {
            for i in 1..w - 1 {
                let (u, v) = (i as f32 / w as f32 - 0.5, j as f32 / h as f32 - 0.5);
                let a = strength * (1.0 - 4.0 * (u * u + v * v)).max(0.0).powi(2);
                sx[j * w + i] = w as f32 * (u * a.cos() - v * a.sin() - u);
                sy[j * w + i] = h as f32 * (u * a.sin() + v * a.cos() - v);
            }
        }
        cases.push((sx, sy, w, h));
    }
    let mut all_steps = [0usize; 3];
    for (dx, dy, w, h) in cases {
        let mut a = vec![0.0; 2 * w * h];
        let mut b = vec![0.0; 2 * w * h];
        invert::invert(&dx, &dy, w, h, Vec2::new(1.0, 0.0), &mut a);
        invert::invert_per_texel(&dx, &dy, w, h, Vec2::new(1.0, 0.0), &mut b);
        let differ = a.iter().zip(&b).filter(|(p, q)| p.to_bits() != q.to_bits()).count();
        assert_eq!(differ, 0, "{w}×{h}: {differ} values differ");
        let mut steps = [0usize; 3];
        for y in 0..h {
            for x in 0..w {
                if dx[y * w + x] != 0.0 || dy[y * w + x] != 0.0 {
                    steps[invert::walk(&dx, &dy, w, h, x, y).1.min(3) - 1] += 1;
                }
            }
        }
        eprintln!("{w}×{h}: texels found in the first, second, a later cell: {steps:?}");
        all_steps.iter_mut().zip(steps).for_each(|(a, s)| *a += s);
    }
    assert!(all_steps.iter().all(|&s| s > 0), "every round must be exercised: {all_steps:?}");
}

#[test]
fn fast_kernels_match_the_reference_kernels() {
    // Cold then warm solves of the bent cylinder; equal as numbers (the
    // reference's min/max may pick the other signed zero).
    for orientation in [0.05, 0.0] {
        let (m, warp) = cylinder_warp(true);
        let mut fast = warp.clone();
        let mut slow = warp;
        fast.settings.orientation = orientation;
        slow.settings.orientation = orientation;
        slow.tiles[0].solver.reference = true;
        for amount in [0.8, 1.0] {
            fast.solve(&bent(&m, amount)).unwrap();
            slow.solve(&bent(&m, amount)).unwrap();
            let (a, b) = (fast.tiles[0].displacement(), slow.tiles[0].displacement());
            let differ = a.0.iter().zip(b.0).chain(a.1.iter().zip(b.1)).filter(|(p, q)| p != q).count();
            assert_eq!(differ, 0, "orientation {orientation}, bend {amount}: {differ} values differ");
        }
    }
}

/// The benchmark's scene (`benches/warp.rs`): 256 × 128 quads, square scales
/// over 25 % of the chart, at its strongest bend (the +X side squashed to
/// half), default settings solved from the identity.
fn benchmark_cylinder(n: usize, variant: solver::Variant) -> (Vec<Vec3>, UvWarp) {
    let m = super::fixtures::uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05);
    let rig = super::fixtures::scales_map(n, n, 24);
    let settings = WarpSettings { warm_start: false, ..Default::default() };
    let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).unwrap();
    warp.tiles[0].solver.set_variant(variant);
    (bend(&m.positions, 2, 0, 0.0, 0.0, 0.5), warp)
}

/// The tests' own scene at grid size `n`: the cylinder of [`cylinder`] with
/// the rigid squares of [`squares`] (scaled to `n`), at full bend, default
/// settings solved from the identity.
fn squares_cylinder(n: usize) -> (Vec<Vec3>, UvWarp) {
    let m = cylinder();
    let s = 0.06;
    let r = rectangles(n, n, &[(0.7 - s, 0.5 - s, 0.7 + s, 0.5 + s), (0.3 - s, 0.5 - s, 0.3 + s, 0.5 + s)]);
    let settings = WarpSettings { warm_start: false, ..Default::default() };
    let warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &r, mask: None }], settings).unwrap();
    (bent(&m, 1.0), warp)
}

/// Cold solves at each of `counts` iterations: no fold-over, nothing for the
/// end-of-solve repair to do (the iterations themselves never folded), and
/// the warp still does its job. Returns the solves that broke that.
fn cold_fold_failures(def: &[Vec3], warp: &mut UvWarp, counts: impl IntoIterator<Item = u32>) -> Vec<String> {
    let mut failures = Vec::new();
    warp.settings.warm_start = false;
    for k in counts {
        warp.settings.iterations = k;
        warp.solve(def).unwrap();
        let met = &warp.metrics(def).unwrap()[0];
        let repair = warp.tiles[0].solver.last_repair;
        if met.foldovers != 0 || repair != (0, 1.0) || met.stretch_warped.mean >= 0.5 * met.stretch_identity.mean {
            failures.push(format!("{}², {k} iterations: folds {}, repair {repair:?}, rigid stretch {:.4} (identity {:.4})", warp.width, met.foldovers, met.stretch_warped.mean, met.stretch_identity.mean));
        }
    }
    failures
}

/// Cold solves whose iterations themselves never fold (issue 28: the old
/// solver's cold solves folded at 2048² from 8 iterations, at 1024² from
/// 24). CI's share of the sweep: every count 1..64 at 1024² on the
/// benchmark's scene, at 2048² the counts where the old solver folded
/// first and a long solve, on both scenes, and the squares at 4096² with
/// the default count. The full sweep, every count 1..64
/// at 2048² and 4096² on both scenes, is `cold_solves_never_fold_full_sweep`
/// (ignored: about half an hour) and the `warp_convergence` benchmark (the
/// benchmark's scene, recorded by `make bench`).
#[test]
fn cold_solves_never_fold() {
    let (def, mut warp) = benchmark_cylinder(1024, solver::Variant::Cascade);
    let mut failures = cold_fold_failures(&def, &mut warp, 1..=64);
    let (def, mut warp) = benchmark_cylinder(2048, solver::Variant::Cascade);
    failures.extend(cold_fold_failures(&def, &mut warp, [4, 8, 32]));
    // The multigrid (selectable, not the default): a few cycle counts.
    let (def, mut warp) = benchmark_cylinder(1024, solver::Variant::Multigrid);
    failures.extend(cold_fold_failures(&def, &mut warp, [1, 2, 4, 8]));
    let (def, mut warp) = squares_cylinder(2048);
    failures.extend(cold_fold_failures(&def, &mut warp, [4, 8, 13, 32]));
    // Four area passes per iteration left a folded cell here (and at 2048²
    // with 13 iterations), which the repair flattened: rigid stretch 0.37.
    let (def, mut warp) = squares_cylinder(4096);
    failures.extend(cold_fold_failures(&def, &mut warp, [4]));
    assert!(failures.is_empty(), "{failures:#?}");
    // The old solver at 32 iterations: its iterations fold and the repair
    // shrinks the whole warp (the fixture does exercise the folds).
    let (def, mut old) = benchmark_cylinder(1024, solver::Variant::Legacy);
    old.settings.iterations = 32;
    old.solve(&def).unwrap();
    let met = &old.metrics(&def).unwrap()[0];
    assert!(old.tiles[0].solver.last_repair.1 < 1.0, "{:?} {met:?}", old.tiles[0].solver.last_repair);
}

#[test]
#[ignore = "about half an hour: every iteration count 1..64 at 2048² and 4096², two scenes (run with --ignored --release)"]
fn cold_solves_never_fold_full_sweep() {
    let mut failures = Vec::new();
    for n in [2048, 4096] {
        let (def, mut warp) = benchmark_cylinder(n, solver::Variant::Cascade);
        failures.extend(cold_fold_failures(&def, &mut warp, 1..=64));
        let (def, mut warp) = squares_cylinder(n);
        failures.extend(cold_fold_failures(&def, &mut warp, 1..=64));
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The converged warp `x_∞` of a solve: continued until a multigrid cycle
/// moves no node by more than 1e-7 of the grid size, and checked with the
/// finest level's own iteration. Returns what it reached.
fn converge_fully(warp: &mut UvWarp, def: &[Vec3]) -> Convergence {
    let n = warp.width;
    warp.set_variant(solver::Variant::Multigrid);
    warp.settings.iterations = 1;
    warp.solve(def).unwrap();
    warp.converge(def, 1e-7 * n as f32, 600, 50).unwrap()
}

/// At default settings (the cascade, 4 iterations) a cold solve's rigid
/// stretch error is within 10 % of the converged warp's `x_∞` (the finest
/// level's fixed point, reached with the multigrid) at the node's default
/// 1024²; the multigrid's single cycle is, at 256² and 1024². The cascade
/// at 256² is not (+73 %: below 512² it is not accelerated), and at 2048²
/// neither (+17 %, the `warp_convergence` benchmark).
#[test]
fn cold_default_solve_is_within_ten_percent_of_converged() {
    for n in [256, 1024] {
        let (def, mut warp) = benchmark_cylinder(n, solver::Variant::Cascade);
        assert_eq!(warp.settings.iterations, WarpSettings::default().iterations);
        warp.solve(&def).unwrap();
        let cascade = warp.metrics(&def).unwrap()[0].stretch_warped.mean;
        warp.set_variant(solver::Variant::Multigrid);
        warp.settings.iterations = 1;
        warp.solve(&def).unwrap();
        let cycle = warp.metrics(&def).unwrap()[0].stretch_warped.mean;
        let reached = converge_fully(&mut warp, &def);
        let met = &warp.metrics(&def).unwrap()[0];
        let converged = met.stretch_warped.mean;
        eprintln!("{n}²: rigid stretch cold, cascade default {cascade:.4}, multigrid 1 cycle {cycle:.4}, converged {converged:.4} (identity {:.4}); {reached:?}", met.stretch_identity.mean);
        // The tolerance is 1e-7 of the grid size per iteration; at
        // this bend a few hundred skin cells sit at the fold-prevention
        // limit and keep nodes moving by 2–4e-4 texel a cycle at 256² (the
        // rigid stretch no longer changes in its fourth digit), so x_inf is
        // known to 1e-3 texel there (docs/performance.md).
        assert!(reached.cycle_change < 1e-3, "{n}²: x_inf not reached: {reached:?}");
        assert_eq!(met.foldovers, 0, "{met:?}");
        assert!((cycle / converged - 1.0).abs() <= 0.10, "{n}²: multigrid {cycle:.4} against converged {converged:.4}");
        if n == 1024 {
            assert!((cascade / converged - 1.0).abs() <= 0.10, "{n}²: cascade {cascade:.4} against converged {converged:.4}");
        }
    }
}

/// More multigrid cycles converge to the finest level's own fixed point:
/// the warp after each further cycle is closer to `x_∞` than the one
/// before (the cascade's cold solves ended 1.2 × the warp's size away from
/// it at 1024², and more iterations did not bring them closer), and `x_∞`
/// is a fixed point of the finest level's iteration (its plain iterations
/// barely move it). Mild bend, where no cell sits at the fold-prevention
/// limit (see docs/performance.md for the strongest one).
#[test]
fn more_cycles_converge_to_the_finest_fixed_point() {
    let n = 256;
    let (_, mut warp) = benchmark_cylinder(n, solver::Variant::Multigrid);
    let m = super::fixtures::uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05);
    let def = bend(&m.positions, 2, 0, 0.0, 0.0, 0.3);
    let valid = warp.tiles[0].validity().to_vec();
    let mut solves = Vec::new();
    for k in [1, 2, 4, 8, 16] {
        warp.settings.iterations = k;
        warp.solve(&def).unwrap();
        solves.push(warp.tiles[0].redirection.clone());
    }
    let reached = converge_fully(&mut warp, &def);
    assert!(reached.cycle_change < 1e-7 * n as f32 && reached.iteration_change < 1e-7 * n as f32, "{reached:?}");
    let inf = warp.tiles[0].redirection.clone();
    let errors: Vec<f64> = solves.iter().map(|r| redirection_difference(r, &inf, &valid, n)).collect();
    eprintln!("convergence error at 1, 2, 4, 8, 16 cycles: {errors:.4?}; {reached:?}");
    assert!(errors.windows(2).all(|e| e[1] < e[0]), "{errors:?}");
    assert!(errors[4] < 0.25 * errors[0], "{errors:?}");
}

/// RMS|a − b| ÷ RMS|b − identity| over the texels inside the chart: the
/// issue's convergence error of redirection `a` when `b` is the converged one.
fn redirection_difference(a: &[f32], b: &[f32], valid: &[u8], n: usize) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (t, _) in valid.iter().enumerate().filter(|(_, &v)| v != 0) {
        let id = [((t % n) as f64 + 0.5) / n as f64, ((t / n) as f64 + 0.5) / n as f64];
        for c in 0..2 {
            num += (a[2 * t + c] as f64 - b[2 * t + c] as f64).powi(2);
            den += (b[2 * t + c] as f64 - id[c]).powi(2);
        }
    }
    (num / den.max(1e-300)).sqrt()
}

/// Issue 28, the multigrid (selectable, not the default): bakes that differ
/// only in the cycle count differ by at most 5 % (convergence error of each
/// frame against the same bake at 64 cycles a frame): the benchmark
/// cylinder's moving bend, frames 0..=10 of `benches/warp.rs`, at 256².
///
/// Holds for warm bakes at 4 cycles a frame or more from frame 2 on. **Not
/// for 1 (or 2) cycles a frame, nor for any bake's first, cold
/// frame:** a cycle removes only 15–25 % of the distance to the converged
/// warp on this scene, so warm frames of a moving bend fall behind (about
/// 0.10 at 1 cycle), and the frame time allows one cycle at 1024²; a cold
/// frame stops where its cycles left it. Settling cold solves to a
/// tolerance fixed the first frame here but not on Spot (docs/performance.md).
/// The last assertion pins one cycle a frame where it was measured.
#[test]
fn multigrid_bakes_that_differ_in_the_count_agree_where_measured() {
    let n = 256;
    let m = super::fixtures::uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05);
    let rig = super::fixtures::scales_map(n, n, 24);
    let pose = |f: usize| bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * (0.6 + 0.04 * f as f32));
    let bake = |k: u32, warm_start: bool, frames: &[usize]| {
        let settings = WarpSettings { iterations: k, warm_start, ..Default::default() };
        let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).unwrap();
        warp.set_variant(solver::Variant::Multigrid);
        let out: Vec<Vec<f32>> = frames
            .iter()
            .map(|&f| {
                warp.solve(&pose(f)).unwrap();
                assert_eq!(warp.metrics(&pose(f)).unwrap()[0].foldovers, 0, "{k} cycles, frame {f}");
                warp.tiles[0].redirection.clone()
            })
            .collect();
        (out, warp.tiles[0].validity().to_vec())
    };
    let differences = |a: &[Vec<f32>], b: &[Vec<f32>], valid: &[u8]| -> Vec<f64> { a.iter().zip(b).map(|(a, b)| redirection_difference(a, b, valid, n)).collect() };
    let one = 1;
    // Warm bakes.
    let all: Vec<usize> = (0..=10).collect();
    let (reference, valid) = bake(64, true, &all);
    let d = differences(&bake(4, true, &all).0, &reference, &valid);
    eprintln!("warm bake, 4 cycles a frame against 64: {d:.3?}");
    assert!(d[2..].iter().all(|&d| d <= 0.05), "warm bake, 4 cycles a frame against 64: {d:.3?}");
    let d = differences(&bake(one, true, &all).0, &reference, &valid);
    eprintln!("warm bake, 1 cycle a frame against 64: {d:.3?}");
    assert!(d.iter().all(|&d| d <= 0.30), "the 1-cycle warm bake is further behind than measured: {d:.3?}");
}

/// Issue 28: bakes at the default (the cascade) that differ only in an
/// iteration count at or beyond the default differ by at most 5 %
/// (convergence error of the shorter bake's frames against the longer
/// one's). The benchmark cylinder's warm bake, frames 0..=10 of
/// `benches/warp.rs`, at 256².
///
/// Not met: 4 against 64 iterations differ by 0.26–0.31 per frame at 256²
/// (0.10–0.23 at 1024²), 16 against 64 by 0.09–0.18. The cascade has no
/// coarse-grid correction, so it never reaches the finest level's fixed
/// point; the multigrid does, but at a cost the frame budget does not
/// allow yet (`multigrid_bakes_that_differ_in_the_count_agree_where_measured`).
#[test]
#[ignore = "fails today: the UV warp half of issue 28 is unfinished (see the doc comment)"]
fn bakes_beyond_the_default_iteration_count_agree_within_five_percent() {
    let n = 256;
    let m = super::fixtures::uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05);
    let rig = super::fixtures::scales_map(n, n, 24);
    let bake = |k: u32| {
        let settings = WarpSettings { iterations: k, warm_start: true, ..Default::default() };
        let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).unwrap();
        let frames: Vec<Vec<f32>> = (0..=10)
            .map(|f| {
                warp.solve(&bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * (0.6 + 0.04 * f as f32))).unwrap();
                warp.tiles[0].redirection.clone()
            })
            .collect();
        (frames, warp.tiles[0].validity().to_vec())
    };
    let default = WarpSettings::default().iterations;
    let (reference, valid) = bake(64);
    let mut worst = Vec::new();
    for k in [default, 2 * default, 16] {
        let (frames, _) = bake(k);
        let d = frames.iter().zip(&reference).map(|(a, b)| redirection_difference(a, b, &valid, n)).fold(0.0, f64::max);
        worst.push((k, d));
    }
    assert!(worst.iter().all(|&(_, d)| d <= 0.05), "largest difference per frame against 64 iterations: {worst:?}");
}

/// Convergence error of the finest warp against `x_∞` (displacements):
/// RMS|x − x_∞| ÷ RMS|x_∞|.
fn displacement_error(warp: &UvWarp, inf: &(Vec<f32>, Vec<f32>)) -> f64 {
    let (dx, dy) = warp.tiles[0].displacement();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for t in 0..dx.len() {
        num += ((dx[t] - inf.0[t]) as f64).powi(2) + ((dy[t] - inf.1[t]) as f64).powi(2);
        den += (inf.0[t] as f64).powi(2) + (inf.1[t] as f64).powi(2);
    }
    (num / den.max(1e-300)).sqrt()
}

/// How the multigrid's finest cycles run in [`cycle_errors_of`].
#[derive(Debug, Clone, Copy)]
struct CycleKind {
    label: &'static str,
    /// Anderson acceleration's depth (0: off).
    anderson: usize,
}

const FAS: CycleKind = CycleKind { label: "FAS", anderson: 0 };

/// Per-cycle error of the multigrid's finest cycles of each kind, from the
/// same cold start, on a scene: for each kind, the errors after the cold
/// solve and after 1..=cycles warm cycles.
fn cycle_errors_of(def: &[Vec3], warp: &mut UvWarp, cycles: usize, kinds: &[CycleKind]) -> Vec<Vec<f64>> {
    warp.set_anderson(0, false);
    let reached = converge_fully(warp, def);
    eprintln!("x_inf: {reached:?}");
    let inf = { let (x, y) = warp.tiles[0].displacement(); (x.to_vec(), y.to_vec()) };
    let mut out = Vec::new();
    for kind in kinds {
        warp.set_variant(solver::Variant::Multigrid);
        // The warm cycles below solve the same pose: the history carries over.
        warp.set_anderson(kind.anderson, true);
        warp.settings.iterations = 1;
        warp.settings.warm_start = false;
        let started = std::time::Instant::now();
        warp.solve(def).unwrap();
        let cold_ms = started.elapsed().as_secs_f64() * 1e3;
        let mut errors = vec![displacement_error(warp, &inf)];
        warp.settings.warm_start = true;
        let started = std::time::Instant::now();
        for _ in 0..cycles {
            warp.solve(def).unwrap();
            errors.push(displacement_error(warp, &inf));
        }
        let per_cycle_ms = started.elapsed().as_secs_f64() * 1e3 / cycles as f64;
        let met = &warp.metrics(def).unwrap()[0];
        let factor = (errors[cycles] / errors[0]).powf(1.0 / cycles as f64);
        let solver = &warp.tiles[0].solver;
        eprintln!("{}²: {} (Anderson {}) cold {cold_ms:.0} ms, warm cycle {per_cycle_ms:.1} ms, errors {errors:.4?}, {factor:.3} a cycle, folds {}, rigid stretch {:.4}, round trip {:.2}, Anderson accepted/rejected {:?}", warp.width, kind.label, kind.anderson, met.foldovers, met.stretch_warped.mean, met.round_trip_max, solver.anderson_counts());
        out.push(errors);
    }
    warp.set_anderson(0, false);
    out
}

/// Issue 28, measured (not a gate): per-cycle reduction of FAS cycles,
/// plain and Anderson-accelerated, on the benchmark cylinder, the squares
/// scene and Spot (`TEGUMENT_WARP_N=256 cargo test --release -p
/// tegument-core --lib anderson_per_cycle -- --ignored --nocapture`).
#[test]
#[ignore = "a measurement: prints per-cycle reductions (release, minutes)"]
fn anderson_per_cycle() {
    let n: usize = std::env::var("TEGUMENT_WARP_N").ok().and_then(|v| v.parse().ok()).unwrap_or(256);
    let cycles: usize = std::env::var("TEGUMENT_WARP_CYCLES").ok().and_then(|v| v.parse().ok()).unwrap_or(8);
    let kinds = [FAS, CycleKind { label: "FAS", anderson: 3 }, CycleKind { label: "FAS", anderson: 6 }];
    let (def, mut warp) = benchmark_cylinder(n, solver::Variant::Multigrid);
    cycle_errors_of(&def, &mut warp, cycles, &kinds);
    let (def, mut warp) = squares_cylinder(n);
    cycle_errors_of(&def, &mut warp, cycles, &kinds);
    let dir = spot_dir();
    if dir.join("spot_triangulated.obj").exists() {
        let m = read_obj(&dir.join("spot_triangulated.obj"));
        let r = spot_rigidity(&dir, n);
        let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &r, mask: None }], settings(false)).unwrap();
        let def = bend(&m.positions, 2, 1, 0.0, -0.7, 0.5);
        cycle_errors_of(&def, &mut warp, cycles, &kinds);
    }
}

/// Issue 28, gate of the Anderson acceleration (selectable, not the
/// default): on the squares scene at 256² its cycles reduce the error
/// faster than plain FAS cycles (measured 0.54 a cycle against 0.82,
/// docs/performance.md) and never fold; on the benchmark cylinder's
/// strongest bend (cells at the fold-prevention limit) it still ends closer
/// to the converged warp than the plain cycles after 6 cycles, without a fold.
#[test]
fn anderson_accelerated_cycles_beat_plain_fas_cycles() {
    let anderson = CycleKind { label: "FAS", anderson: 3 };
    let factor = |e: &[f64]| (e[6] / e[0]).powf(1.0 / 6.0);
    let (def, mut warp) = squares_cylinder(256);
    let out = cycle_errors_of(&def, &mut warp, 6, &[FAS, anderson]);
    assert!(factor(&out[1]) <= 0.7 && factor(&out[1]) < factor(&out[0]), "FAS {:.4?}, Anderson {:.4?}", out[0], out[1]);
    let (def, mut warp) = benchmark_cylinder(256, solver::Variant::Multigrid);
    let out = cycle_errors_of(&def, &mut warp, 6, &[FAS, anderson]);
    assert!(out[1][6] < 0.7 * out[0][6], "FAS {:.4?}, Anderson {:.4?}", out[0], out[1]);
    for (def, mut warp) in [squares_cylinder(256), (def, warp)] {
        warp.set_variant(solver::Variant::Multigrid);
        warp.set_anderson(3, true);
        let failures = cold_fold_failures(&def, &mut warp, [1, 4, 8]);
        assert!(failures.is_empty(), "{failures:#?}");
        let (accepted, _) = warp.tiles[0].solver.anderson_counts().unwrap();
        assert!(accepted > 0, "no Anderson step was taken in the cold solves");
    }
}

/// Issue 28, measured (not a gate): bakes of the benchmark cylinder's moving
/// bend (frames 0..=10, frame 0 cold) at k cycles a frame, plain FAS and
/// Anderson-accelerated (history kept across the warm frames), against the
/// bake at 64 plain cycles a frame (`TEGUMENT_WARP_N=256 cargo test
/// --release -p tegument-core --lib anderson_bakes -- --ignored --nocapture`).
#[test]
#[ignore = "a measurement: prints bake differences (release, minutes)"]
fn anderson_bakes_against_64_cycles() {
    let n: usize = std::env::var("TEGUMENT_WARP_N").ok().and_then(|v| v.parse().ok()).unwrap_or(256);
    let m = super::fixtures::uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05);
    let rig = super::fixtures::scales_map(n, n, 24);
    let pose = |f: usize| bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * (0.6 + 0.04 * f as f32));
    let bake = |k: u32, depth: usize, across: bool| {
        let settings = WarpSettings { iterations: k, warm_start: true, ..Default::default() };
        let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).unwrap();
        warp.set_variant(solver::Variant::Multigrid);
        warp.set_anderson(depth, across);
        let mut ms = Vec::new();
        let mut folds = 0;
        let frames: Vec<Vec<f32>> = (0..=10)
            .map(|f| {
                let started = std::time::Instant::now();
                warp.solve(&pose(f)).unwrap();
                ms.push(started.elapsed().as_secs_f64() * 1e3);
                folds += warp.metrics(&pose(f)).unwrap()[0].foldovers;
                warp.tiles[0].redirection.clone()
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        (frames, warp.tiles[0].validity().to_vec(), ms[ms.len() / 2], folds, warp.tiles[0].solver.anderson_counts())
    };
    let (reference, valid, ..) = bake(64, 0, false);
    for k in [1, 2, 4, 8] {
        for (depth, across) in [(0, false), (3, false), (3, true), (6, true)] {
            if k == 1 && depth > 0 && !across {
                continue;
            }
            let (frames, _, ms, folds, counts) = bake(k, depth, across);
            let d: Vec<f64> = frames.iter().zip(&reference).map(|(a, b)| redirection_difference(a, b, &valid, n)).collect();
            let worst_warm = d[1..].iter().cloned().fold(0.0, f64::max);
            eprintln!("{n}²: {k} cycles a frame, Anderson {depth} (across frames {across}): against 64 {d:.3?}, worst warm {worst_warm:.3}, median frame {ms:.1} ms, folds {folds}, accepted/rejected {counts:?}");
        }
    }
}

/// Issue 28, measured (not a gate): the wall time of a warm frame of the
/// benchmark cylinder's strongest bend, alternating in rounds between the
/// cascade (the default), one plain FAS cycle and one Anderson-accelerated
/// FAS cycle, medians over the rounds (`TEGUMENT_WARP_N=1024 cargo test
/// --release -p tegument-core --lib anderson_cycle_cost -- --ignored
/// --nocapture`; run beside `uptime`).
#[test]
#[ignore = "a measurement: prints frame times (release)"]
fn anderson_cycle_cost() {
    let n: usize = std::env::var("TEGUMENT_WARP_N").ok().and_then(|v| v.parse().ok()).unwrap_or(1024);
    let kinds: [(&str, solver::Variant, usize); 3] = [("cascade", solver::Variant::Cascade, 0), ("FAS cycle", solver::Variant::Multigrid, 0), ("FAS cycle + Anderson 3", solver::Variant::Multigrid, 3)];
    let mut warps: Vec<(Vec<Vec3>, UvWarp)> = kinds
        .iter()
        .map(|&(_, variant, depth)| {
            let (def, mut warp) = benchmark_cylinder(n, variant);
            warp.set_anderson(depth, false);
            warp.settings.iterations = if variant == solver::Variant::Cascade { WarpSettings::default().iterations } else { 2 };
            warp.settings.warm_start = true;
            warp.solve(&def).unwrap();
            (def, warp)
        })
        .collect();
    let mut times = vec![Vec::new(); kinds.len()];
    for _ in 0..7 {
        for (k, (def, warp)) in warps.iter_mut().enumerate() {
            let started = std::time::Instant::now();
            warp.solve(def).unwrap();
            times[k].push(started.elapsed().as_secs_f64() * 1e3);
        }
    }
    for (k, t) in times.iter_mut().enumerate() {
        t.sort_by(f64::total_cmp);
        eprintln!("{n}²: {} ({} a frame) warm frame median {:.1} ms, all {t:.1?}", kinds[k].0, warps[k].1.settings.iterations, t[t.len() / 2]);
    }
}

/// Issue 28, measured (not a gate): work-counted iteration counts for small
/// grids with the default cascade. A 256² iteration costs 1/16 of a 1024²
/// one, so 256² could run 16 × the count in the same frame time: cold rigid
/// stretch of the benchmark cylinder's strongest bend against its converged
/// warp, and Spot's round trip, by count (`cargo test --release -p
/// tegument-core --lib cascade_counts_at_256 -- --ignored --nocapture`).
#[test]
#[ignore = "a measurement: prints rigid stretch and round trips by count (release)"]
fn cascade_counts_at_256() {
    let n = 256;
    let (def, mut warp) = benchmark_cylinder(n, solver::Variant::Multigrid);
    converge_fully(&mut warp, &def);
    let converged = warp.metrics(&def).unwrap()[0].stretch_warped.mean;
    warp.set_variant(solver::Variant::Cascade);
    for k in [4u32, 8, 16, 32, 64] {
        warp.settings.iterations = k;
        warp.settings.warm_start = false;
        warp.solve(&def).unwrap();
        let met = &warp.metrics(&def).unwrap()[0];
        eprintln!("cylinder 256², cascade {k}: rigid stretch {:.4} against converged {converged:.4} ({:+.1} %), folds {}, round trip {:.2}", met.stretch_warped.mean, 100.0 * (met.stretch_warped.mean / converged - 1.0), met.foldovers, met.round_trip_max);
    }
    let dir = spot_dir();
    if dir.join("spot_triangulated.obj").exists() {
        let m = read_obj(&dir.join("spot_triangulated.obj"));
        let r = spot_rigidity(&dir, n);
        let def = bend(&m.positions, 2, 1, 0.0, -0.7, 0.5);
        for k in [8u32, 16, 32, 64, 128] {
            let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &r, mask: None }], WarpSettings { iterations: k, warm_start: false, ..Default::default() }).unwrap();
            warp.solve(&def).unwrap();
            let met = &warp.metrics(&def).unwrap()[0];
            eprintln!("Spot 256², cascade {k}: rigid stretch {:.4} (identity {:.4}), p95 {:.3}, folds {}, round trip {:.2}", met.stretch_warped.mean, met.stretch_identity.mean, met.stretch_warped.p95, met.foldovers, met.round_trip_max);
        }
    }
}
