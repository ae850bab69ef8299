"""Robustness battery of the wheel: each bad input gets a message naming it, and nothing is lost.

"Nothing lost" at this level: the caller's arrays are not modified, a file
that cannot be written leaves no file (and no temporary file) behind, an
existing file is replaced whole or not at all, and an object that refused a
call still works afterwards.
"""

from __future__ import annotations

import os
import pathlib
import re
import struct
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest

import tegument
from conftest import cube_arrays, grid_arrays
from test_collide import uv_sphere


def frozen(*arrays):
    """Copies to compare against after the call: the wheel must never write into its inputs."""
    return [np.array(a, copy=True) for a in arrays]


def assert_unchanged(before, after):
    for b, a in zip(before, after):
        np.testing.assert_array_equal(a, b)


# -------------------------------------------------------------- mesh topology

def mesh_from(vertices, faces):
    positions = np.array(vertices, np.float32)
    corners = np.array([v for f in faces for v in f], np.int32)
    sizes = np.array([len(f) for f in faces], np.int32)
    return positions, corners, sizes


CUBE_VERTS = [(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
CUBE_FACES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]

TOPOLOGY_CASES = {
    # name: (mesh, expected report entries, pinned vertices must include). Irregular vertices with at
    # least two neighbours (non-manifold, flipped, zero-area, border corners) are not pinned: they keep
    # their offset from their neighbours (a ring fit); only those without (loose, in no usable face) are.
    "non-manifold edge (three faces)": (
        mesh_from([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, 1), (0, 0, 1), (0, -1, 0), (1, -1, 0)],
                  [(0, 1, 2, 3), (1, 0, 5, 4), (0, 1, 7, 6)]),
        {"non_manifold_edges": 1}, []),
    "loose vertex": (mesh_from(CUBE_VERTS + [(5, 5, 5)], CUBE_FACES), {"isolated_vertices": 1}, [8]),
    "n-gon caps (hexagonal prism)": (
        mesh_from([(np.cos(a), np.sin(a), z) for z in (0, 1) for a in np.linspace(0, 2 * np.pi, 7)[:-1]],
                  [tuple(range(5, -1, -1)), tuple(range(6, 12))] + [(i, (i + 1) % 6, 6 + (i + 1) % 6, 6 + i) for i in range(6)]),
        {"is_closed_manifold": True, "degenerate_polygons": 0}, []),
    "zero-area face": (mesh_from([(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0)], [(0, 1, 2), (0, 1, 3)]),
                       {"degenerate_polygons": 1}, []),
    "duplicate vertices (unwelded seam)": (
        mesh_from([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0)],
                  [(0, 1, 2, 3), (4, 5, 6, 7)]),
        # Welded for the solver: one 2×1 sheet (its corners ring-fitted).
        {"boundary_vertices": 8, "is_clean": True}, []),
    "flipped face": (mesh_from(CUBE_VERTS, CUBE_FACES[:-1] + [tuple(reversed(CUBE_FACES[-1]))]),
                     {"flipped_edges": 4}, []),
    "repeated corner in a polygon": (mesh_from([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 1, 2)]),
                                     {"degenerate_polygons": 1}, [0, 1, 2]),
}


@pytest.mark.parametrize("name", TOPOLOGY_CASES)
def test_unusual_topology_is_reported_and_bindable(name):
    (positions, corners, sizes), expected, pinned = TOPOLOGY_CASES[name]
    before = frozen(positions, corners, sizes)
    report = tegument.Mesh(positions, corners, sizes).report
    for key, value in expected.items():
        assert getattr(report, key) == value, (name, key, report)
    deformer = tegument.PyramidDeformer(positions, corners, sizes)
    assert set(pinned) <= set(deformer.pinned_vertices.tolist()), (name, deformer.pinned_vertices)
    moved = positions * 1.5 + np.float32(0.25)
    out = deformer.solve(moved, iterations=5)
    assert np.isfinite(out).all()
    # The vertices that cannot be encoded follow the input exactly.
    np.testing.assert_array_equal(out[deformer.pinned_vertices], moved[deformer.pinned_vertices])
    assert_unchanged(before, (positions, corners, sizes))


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda p, c, s: (p, c, np.array([4, 4, 4, 4, 4, 3], np.int32)), r"polygon sizes add up to 23 corners but 24"),
        (lambda p, c, s: (p, c, np.array([4, 4, 4, 4, 4, 2], np.int32)), r"polygon 5 has 2 corners; a polygon needs at least 3"),
        (lambda p, c, s: (p, np.where(c == 7, 8, c).astype(np.int32), s), r"corner 6 refers to vertex 8, but the mesh has 8 vertices"),
        (lambda p, c, s: (p, np.where(c == 7, -1, c).astype(np.int32), s), r"refers to vertex -1"),
        (lambda p, c, s: (np.where(np.arange(24).reshape(8, 3) == 10, np.nan, p).astype(np.float32), c, s), r"positions: vertex 3 is not finite"),
        (lambda p, c, s: (p.astype(np.complex64), c, s), r"positions: expected float32 \(N, 3\) \(other float types are converted\); got complex64 \(8, 3\)"),
        (lambda p, c, s: (p, c.astype(bool), s), r"corner_verts: expected int32"),
        (lambda p, c, s: (p, c.astype(np.float32), s), r"corner_verts: expected int32"),
        (lambda p, c, s: (p, c.tolist(), s), r"corner_verts: expected int32 \(N,\) \(other integer types are converted\); got a list"),
    ],
)
def test_bad_mesh_arrays_name_the_problem(mutate, message):
    positions, corners, sizes = mutate(*cube_arrays())
    for constructor in (tegument.Mesh, tegument.PyramidDeformer):
        with pytest.raises(tegument.TegumentError, match=message):
            constructor(positions, corners, sizes)


def test_upstream_vertex_count_change_after_bind_is_refused(cube):
    deformer = tegument.PyramidDeformer(*cube)
    with pytest.raises(tegument.TegumentError, match=r"positions: expected float32 \(8, 3\).*got float32 \(9, 3\)"):
        deformer.solve(np.zeros((9, 3), np.float32))
    assert np.isfinite(deformer.solve(cube[0])).all()  # still usable


def test_non_finite_and_huge_input_positions(cube):
    deformer = tegument.PyramidDeformer(*cube)
    for bad, message in ((np.nan, "vertex 5 is not finite"), (np.inf, "vertex 5 is not finite"), (-np.inf, "vertex 5 is not finite")):
        positions = cube[0].copy()
        positions[5, 1] = bad
        with pytest.raises(tegument.TegumentError, match=message):
            deformer.solve(positions)
    positions = cube[0] * np.float32(1e37)  # finite, but squares overflow float32
    try:
        out = deformer.solve(positions)
    except tegument.TegumentError as error:
        assert "not finite" in str(error) or "non-finite" in str(error)
    else:
        assert np.isfinite(out).all()


def test_iteration_count_is_bounded(cube):
    deformer = tegument.PyramidDeformer(*cube)
    with pytest.raises(tegument.TegumentError, match=r"iterations is 10000001; at most 100000 are allowed"):
        deformer.solve(cube[0], iterations=10_000_001)
    with pytest.raises(tegument.TegumentError, match="closeness"):
        deformer.solve(cube[0], closeness=np.full(8, np.nan, np.float32))


# ----------------------------------------------------------- memory limits

def run_python(code: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          env={**os.environ, **env}, timeout=120)


def test_a_mesh_above_the_memory_limit_is_refused_with_the_amount_needed():
    result = run_python(
        """
        import numpy as np, tegument
        n = 20000
        positions = np.random.default_rng(0).random((n, 3), dtype=np.float32)
        corners = np.arange(n - n % 3, dtype=np.int32)
        sizes = np.full(len(corners) // 3, 3, np.int32)
        for make in (tegument.Mesh, tegument.PyramidDeformer):
            try:
                make(positions, corners, sizes)
            except tegument.TegumentError as error:
                print("refused:", error)
            else:
                print("accepted")
        """,
        TEGUMENT_MEMORY_LIMIT="1M",
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 2 and all(line.startswith("refused:") for line in lines), result.stdout
    assert re.search(r"a mesh of 20000 vertices and 19998 face corners would need \d+ bytes \([\d.]+ MiB\), "
                     r"more than the limit of 1048576 bytes \(1\.0 MiB\)", lines[0]), lines[0]


def test_an_unreadable_limit_falls_back_to_the_default():
    result = run_python(
        """
        import numpy as np, tegument
        positions = np.zeros((3, 3), np.float32); positions[1, 0] = positions[2, 1] = 1
        print(tegument.Mesh(positions, np.array([0, 1, 2], np.int32), np.array([3], np.int32)).vertex_count)
        """,
        TEGUMENT_MEMORY_LIMIT="lots",
    )
    assert result.returncode == 0 and result.stdout.strip() == "3", result.stderr


def test_a_uv_warp_grid_above_the_limit_is_refused_with_the_amount_needed():
    positions, corners, sizes, uvs = uv_quad()
    with pytest.raises(tegument.TegumentError,
                       match=r"a UV warp of 1 tile\(s\) of 1024×1024 would need \d+ bytes \([\d.]+ MiB\), more than the limit "
                             r"of 16777216 bytes \(16.0 MiB\)"):
        tegument.UvWarp(positions, corners, sizes, uvs, np.ones((1024, 1024), np.float32), memory_limit=16 << 20)
    with pytest.raises(tegument.TegumentError, match=r"would need \d+ bytes .* more than the limit of 1000 bytes"):
        tegument.UvWarp(positions, corners, sizes, uvs, np.ones((8, 8), np.float32), memory_limit=1000)


# -------------------------------------------------------------------- UV warp

def uv_quad(uv_offset=(0.0, 0.0)):
    positions, corners, sizes = grid_arrays(2, 2)
    uvs = ((positions[:, :2] + 1) / 2 * 0.8 + 0.1)[corners] + np.array(uv_offset, np.float32)
    return positions, corners, sizes, uvs.astype(np.float32)


def test_udim_tiles_need_one_map_each_and_work():
    positions, corners, sizes, uvs = uv_quad()
    uvs[len(uvs) // 2:] += np.array([1, 0], np.float32)  # half the polygons in tile 1002
    with pytest.raises(tegument.TegumentError, match=r"the UVs touch UDIM tile 1002 but no rigidity map was given for it"):
        tegument.UvWarp(positions, corners, sizes, uvs, {1001: np.ones((8, 8), np.float32)})
    warp = tegument.UvWarp(positions, corners, sizes, uvs, {1001: np.ones((8, 8), np.float32), 1002: np.ones((8, 8), np.float32)})
    assert warp.tiles == [1001, 1002]
    out = {udim: warp.solve(positions * np.float32(1.2), udim=udim) for udim in warp.tiles}
    assert set(out) == {1001, 1002} and all(np.isfinite(a).all() for a in out.values())
    with pytest.raises(tegument.TegumentError, match=r"spans UDIM tiles \[1001, 1002\]: say which one"):
        warp.write_exr("unused.exr")


@pytest.mark.parametrize("offset, message", [
    ((-2, 0), r"outside the UDIM range \(u in \[0, 10\), v ≥ 0\)"),
    ((10, 0), r"outside the UDIM range"),
    ((0, -3), r"outside the UDIM range"),
])
def test_uvs_outside_the_udim_range(offset, message):
    positions, corners, sizes, uvs = uv_quad(offset)
    with pytest.raises(tegument.TegumentError, match=message):
        tegument.UvWarp(positions, corners, sizes, uvs, np.ones((8, 8), np.float32))


def test_degenerate_uv_triangles_are_skipped_not_fatal():
    positions, corners, sizes, uvs = uv_quad()
    uvs[:4] = uvs[0]  # the first polygon collapses to a point in UV space
    uvs[4:8, 1] = 0.5  # the second to a line
    warp = tegument.UvWarp(positions, corners, sizes, uvs, np.ones((8, 8), np.float32))
    out = warp.solve(positions * np.float32(1.1))
    assert np.isfinite(out).all()
    metrics = warp.metrics(positions * np.float32(1.1))
    assert np.isfinite(metrics.round_trip_max)


def test_bad_rigidity_and_mask_images():
    positions, corners, sizes, uvs = uv_quad()
    cases = [
        (np.ones((8, 16), np.float32), r"rigidity: expected float32 \(8, 8\) \(other float types are converted\); got float32 \(8, 16\)"),
        (np.ones((8, 8, 3), np.float32), r"rigidity: expected float32 \(8, 8\)"),
        (np.ones((8, 8), np.complex64), r"rigidity: expected float32"),
        (np.full((8, 8), np.nan, np.float32), r"rigidity"),
        ({}, r"rigidity: the dict is empty"),
        ({"1001": np.ones((8, 8), np.float32)}, r"dict keys must be UDIM tile numbers"),
    ]
    for rigidity, message in cases:
        with pytest.raises(tegument.TegumentError, match=message):
            tegument.UvWarp(positions, corners, sizes, uvs, rigidity, shape=(8, 8))
    with pytest.raises(tegument.TegumentError, match=r"mask given for UDIM tile 1005, which has no rigidity map"):
        tegument.UvWarp(positions, corners, sizes, uvs, np.ones((8, 8), np.float32), mask={1005: np.ones((8, 8), np.float32)})
    with pytest.raises(tegument.TegumentError, match=r"corner_uvs: expected float32 \(16, 2\).*one UV per face corner: the mesh has 16 corners"):
        tegument.UvWarp(positions, corners, sizes, uvs[:-1], np.ones((8, 8), np.float32))


# ---------------------------------------------------------------- Collider

def test_collider_problems_name_themselves():
    positions, corners, _ = cube_arrays()
    quads = corners.reshape(-1, 4)
    triangles = np.ascontiguousarray(np.concatenate([quads[:, :3], quads[:, [0, 2, 3]]]), dtype=np.int32)
    with pytest.raises(tegument.TegumentError, match=r"triangles: expected int32 \(T, 3\)"):
        tegument.Collider(positions, triangles.ravel(), thickness=0.0, friction=0.0)
    bad = triangles.copy()
    bad[3, 1] = 8
    with pytest.raises(tegument.TegumentError, match="8"):
        tegument.Collider(positions, bad, thickness=0.0, friction=0.0)
    for kwargs in (dict(thickness=np.nan), dict(thickness=-1.0), dict(friction=np.inf), dict(kinetic_friction=-0.5)):
        with pytest.raises(tegument.TegumentError):
            tegument.Collider(positions, triangles, **kwargs)

    open_collider = tegument.Collider(positions, triangles[:-2], thickness=0.0, friction=0.0)  # one face missing
    assert not open_collider.is_closed
    report = tegument.audit(positions * np.float32(0.1), corners, np.full(6, 4, np.int32), [open_collider])
    assert report.open_colliders == [0] and report.vertices_inside == 0

    collider = tegument.Collider(positions, triangles, thickness=0.0, friction=0.0)
    before = frozen(collider.positions, collider.previous_positions)
    # A collider whose topology changes over time: refused, the collider keeps its state.
    with pytest.raises(tegument.TegumentError, match="collider had 8 vertices, update gave 9"):
        collider.update(np.zeros((9, 3), np.float32))
    moved = positions.copy()
    moved[2] = np.nan
    with pytest.raises(tegument.TegumentError, match="vertex 2 is not finite"):
        collider.update(moved)
    assert_unchanged(before, (collider.positions, collider.previous_positions))
    # A rigid move leaves the refitted tree as good as new: no rebuild.
    rebuilds = collider.bvh_rebuilds
    report = collider.update(positions + np.float32(0.5))
    assert report.rebuilt is False and report.cost_ratio == pytest.approx(1.0, abs=1e-6), report
    assert collider.bvh_rebuilds == rebuilds
    # Vertices shuffled among each other (each triangle now spans the mesh): the refitted
    # tree degrades past the rebuild ratio and is rebuilt.
    sphere, sphere_triangles = uv_sphere(1.0)
    shuffled = tegument.Collider(sphere, sphere_triangles, thickness=0.0, friction=0.0)
    report = shuffled.update(np.ascontiguousarray(sphere[np.random.default_rng(0).permutation(len(sphere))]))
    assert report.rebuilt is True and report.cost_ratio > 1.4 and shuffled.bvh_rebuilds == 1, report
    with pytest.raises(tegument.TegumentError, match=r"colliders\[1\]: expected a tegument.Collider, got str"):
        tegument.audit(positions, corners, np.full(6, 4, np.int32), [collider, "Cube"])
    assert tegument.audit(positions, corners, np.full(6, 4, np.int32), []).vertices_inside == 0


# ------------------------------------------------------------------- OpenEXR

def test_exr_paths_that_cannot_be_written(tmp_path):
    image = np.ones((4, 4, 3), np.float32)
    blocker = tmp_path / "a_file"
    blocker.write_text("keep me")
    for path in (blocker / "x.exr", tmp_path / "missing" / "x.exr", tmp_path):
        with pytest.raises(tegument.TegumentError, match=re.escape(str(path.parent if path != tmp_path else path)) + "|" + re.escape(str(path))):
            tegument.write_exr(str(path), image)
    assert blocker.read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"], "a temporary file was left behind"

    target = tmp_path / "keep.exr"
    tegument.write_exr(str(target), image, {"version": "1"})
    before = target.read_bytes()
    bad = image.copy()
    bad[1, 2, 0] = np.inf
    with pytest.raises(tegument.TegumentError, match=r"channel 0 of texel \(row 1, column 2\) is inf; refusing"):
        tegument.write_exr(str(target), bad)
    with pytest.raises(tegument.TegumentError, match=r'metadata value "é→": OpenEXR text attributes hold Latin-1'):
        tegument.write_exr(str(target), image, {"note": "é→"})
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "keep.exr"]
    assert tegument.read_exr(str(target))[1]["version"] == "1"


def test_damaged_and_oversized_exr_files_are_refused(tmp_path):
    path = tmp_path / "image.exr"
    tegument.write_exr(str(path), np.ones((4, 4), np.float32))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(tegument.TegumentError, match=re.escape(str(path))):
        tegument.read_exr(str(path))
    # A header that promises a 2³⁰ × 2³⁰ image must be refused, not allocated.
    window = data.find(b"dataWindow\0box2i\0")
    assert window > 0
    offset = window + len(b"dataWindow\0box2i\0") + 4
    huge = bytearray(data)
    huge[offset:offset + 16] = struct.pack("<iiii", 0, 0, 2**30 - 1, 2**30 - 1)
    path.write_bytes(bytes(huge))
    with pytest.raises(tegument.TegumentError):
        tegument.read_exr(str(path))
    with pytest.raises(tegument.TegumentError, match="could not read EXR"):
        tegument.read_exr(str(tmp_path / "absent.exr"))


# ------------------------------------------------------------------- threads

def test_calls_from_several_threads_equal_serial_results():
    positions, corners, sizes = grid_arrays(12, 10)
    rng = np.random.default_rng(3)
    inputs = [(positions + rng.normal(0, 0.05, positions.shape)).astype(np.float32) for _ in range(8)]
    shared = tegument.PyramidDeformer(positions, corners, sizes)
    _, _, _, uvs = uv_quad()
    warp_args = uv_quad()[:3]

    def work(k):
        deformer = tegument.PyramidDeformer(positions, corners, sizes)
        mesh = tegument.Mesh(inputs[k], corners, sizes)
        warp = tegument.UvWarp(*warp_args, uvs, np.ones((8, 8), np.float32), warm_start=False)
        collider = tegument.Collider(*cube_arrays()[:1], np.array([[0, 1, 2], [1, 3, 2]], np.int32), thickness=0.0, friction=0.0)
        return (
            deformer.solve(inputs[k], iterations=4),
            shared.solve(inputs[k], iterations=4),  # one object from many threads: serialised, same result
            mesh.edges,
            warp.solve(warp_args[0] * np.float32(1 + 0.05 * k)),
            tegument.audit(inputs[k], corners, sizes, [collider]).edges_crossing,
        )

    serial = [work(k) for k in range(len(inputs))]
    results: dict[int, tuple] = {}
    errors = []

    def run(k):
        try:
            for _ in range(3):
                results[k] = work(k)
        except BaseException as error:  # noqa: BLE001 - reported below
            errors.append(error)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(len(inputs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for k, expected in enumerate(serial):
        for a, b in zip(expected, results[k]):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_panics_unwind_in_every_profile():
    """run_detached turns a Rust panic into TegumentError with catch_unwind, which
    only works when panics unwind: no profile may set panic = "abort". (That a
    panic inside a rayon task unwinds to the caller is tested in the core:
    error::tests::panic_in_parallel_work_reaches_the_caller.)"""
    import tomllib

    root = pathlib.Path(__file__).resolve().parents[3]
    manifests = [root / "Cargo.toml", root / "rust" / "python" / "Cargo.toml", root / "rust" / "core" / "Cargo.toml"]
    for manifest in manifests:
        profiles = tomllib.loads(manifest.read_text()).get("profile", {})
        for name, profile in profiles.items():
            assert profile.get("panic", "unwind") == "unwind", f"{manifest}: profile.{name} sets panic = {profile['panic']!r}"
    pyproject = tomllib.loads((root / "rust" / "python" / "pyproject.toml").read_text())
    assert "panic" not in str(pyproject.get("tool", {}).get("maturin", {})), "maturin must not override the panic strategy"


def test_one_collider_and_one_warp_shared_by_threads_serialise_instead_of_failing():
    """Updating a collider while other threads audit and step against it, and
    solving one UvWarp from several threads: every call waits its turn."""
    positions, corners, sizes = grid_arrays(12, 10)
    cube, _, _ = cube_arrays()
    triangles = np.array([[0, 1, 2], [1, 3, 2]], np.int32)
    collider = tegument.Collider(cube, triangles, thickness=0.0, friction=0.0)
    warp_args = uv_quad()[:3]
    uvs = uv_quad()[3]
    warp = tegument.UvWarp(*warp_args, uvs, np.ones((8, 8), np.float32), warm_start=False)
    expected_warp = warp.solve(warp_args[0] * np.float32(1.05)).copy()
    errors = []

    def run(k):
        deformer = tegument.PyramidDeformer(positions, corners, sizes)
        try:
            for i in range(20):
                if k % 2:
                    collider.update(cube + np.float32(0.001 * i))
                    np.testing.assert_array_equal(warp.solve(warp_args[0] * np.float32(1.05)), expected_warp)
                else:
                    tegument.audit(positions, corners, sizes, [collider])
                    deformer.step(positions, [collider], iterations=2)
        except BaseException as error:  # noqa: BLE001 - reported below
            errors.append(error)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
