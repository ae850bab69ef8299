//! `tegument.UvWarp`, `tegument.write_exr`, `tegument.read_exr`: content-aware
//! UV warps baked into redirection textures.
//!
//! Array convention: images are ``(height, width[, channels])`` float32,
//! row-major, **row 0 is the lowest v** (texel ``(row j, column i)`` covers
//! ``u ∈ [i/width, (i+1)/width)``, ``v ∈ [j/height, (j+1)/height)``), which is
//! the order of Blender's ``Image.pixels``.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::RwLock;

use glam::Vec2;
use numpy::ndarray::{Array2, Array3};
use numpy::IntoPyArray;
use pyo3::prelude::*;
use numpy::{PyUntypedArray, PyUntypedArrayMethods};
use pyo3::types::{PyDict, PyTuple};
use tegument_core::mesh::MeshInput;
use tegument_core::warp::{self, TileMaps, WarpSettings};

use crate::convert::{float_array_arg, float_grid_arg, int_array_arg, positions_arg, run_detached, TegumentError};

/// Content-aware UV warp of one mesh (seed 001: hierarchical position-based
/// dynamics on a UV-space grid).
///
/// ``rest_positions`` float32 ``(N, 3)``; ``corner_verts`` int32 ``(L,)``;
/// ``polygon_sizes`` int32 ``(P,)``; ``corner_uvs`` float32 ``(L, 2)`` in
/// Blender's corner order. ``rigidity`` and ``mask``: float32 ``(height,
/// width)`` in [0, 1] (row 0 = lowest v), or a dict ``{udim: array}`` when the
/// UVs span several UDIM tiles. Rigidity 1 keeps texture detail rigid, 0 lets
/// it stretch with the surface; mask 0 fixes texels (the mask is also 0
/// automatically outside UV charts and on chart borders). The grid of every
/// tile has the shape of its rigidity map, ``(height, width)``, powers of two
/// in [8, 16384]; ``shape=(height, width)`` checks it. (In 0.1.0 the grid
/// size came first, width first: ``UvWarp(width, height, rest_positions, …)``
/// still works, deprecated.)
///
/// Results per tile (:meth:`solve`, :meth:`redirection`, :meth:`validity`,
/// :meth:`displacement`, :meth:`metrics`) are one array or report for one
/// tile: ``udim`` names it, and may be left out when the warp has one tile.
///
/// ``iterations``: PBD iterations on the finest level (coarser levels run
/// more). ``orientation``: fraction in [0, 1] by which rigid segments turn back
/// to their rest direction per iteration. ``smoothing``: the global smoothing
/// factor of rigid regions, in [0, 1]. ``warm_start``: start each solve from the
/// previous one (temporal coherence); ``False`` solves every frame from the
/// identity, deterministically. ``memory_limit``: bytes (default 3 GiB); grids
/// that would need more are refused with the amount they need.
#[pyclass(module = "tegument", name = "UvWarp", frozen)]
pub struct UvWarp {
    // A lock rather than `&mut self`: a solve runs without the GIL, and
    // another Python thread using the same warp meanwhile waits for it
    // instead of getting pyo3's "already borrowed" error.
    inner: RwLock<warp::UvWarp>,
    multi: bool,
}

/// A rigidity or mask argument: one array (tile 1001) or `{udim: array}`.
fn tile_images(name: &str, obj: &Bound<'_, PyAny>, w: usize, h: usize) -> PyResult<BTreeMap<u32, Vec<f32>>> {
    let mut out = BTreeMap::new();
    if let Ok(dict) = obj.cast::<PyDict>() {
        for (k, v) in dict.iter() {
            let udim: u32 = k.extract().map_err(|_| TegumentError::new_err(format!("{name}: dict keys must be UDIM tile numbers (int), got {k}")))?;
            let (_, data) = float_grid_arg(&format!("{name}[{udim}]"), &v, &[Some(h), Some(w)])?;
            out.insert(udim, data);
        }
        if out.is_empty() {
            return Err(TegumentError::new_err(format!("{name}: the dict is empty")));
        }
    } else {
        let (_, data) = float_grid_arg(name, obj, &[Some(h), Some(w)])?;
        out.insert(1001, data);
    }
    Ok(out)
}

fn size_arg(name: &str, v: i64) -> PyResult<usize> {
    let ok = v > 0 && (v as u64).is_power_of_two() && (8..=16384).contains(&v);
    if !ok {
        return Err(TegumentError::new_err(format!("{name} must be a power of two between 8 and 16384, not {v}")));
    }
    Ok(v as usize)
}

/// The `(height, width, 2)` redirection of one tile.
fn redirection_array<'py>(py: Python<'py>, t: &warp::TileWarp, w: usize, h: usize) -> Bound<'py, PyAny> {
    Array3::from_shape_vec((h, w, 2), t.redirection.clone()).expect("2·w·h floats").into_pyarray(py).into_any()
}

/// The `(height, width)` of a rigidity argument (one array or `{udim: array}`),
/// which sets the grid size.
fn rigidity_shape(obj: &Bound<'_, PyAny>) -> PyResult<(i64, i64)> {
    let first = match obj.cast::<PyDict>() {
        Ok(d) => d.values().iter().next(),
        Err(_) => Some(obj.clone()),
    };
    let shape = first.as_ref().and_then(|a| a.cast::<PyUntypedArray>().ok()).map(|a| a.shape().to_vec());
    match shape.as_deref() {
        Some(&[h, w]) => Ok((h as i64, w as i64)),
        _ => Err(TegumentError::new_err(format!(
            "rigidity: expected a float32 (height, width) array (or {{udim: array}}), which sets the grid size; got {}",
            obj.repr().map(|r| r.to_string()).unwrap_or_default().chars().take(80).collect::<String>()
        ))),
    }
}

fn metrics_report<'py>(py: Python<'py>, m: &warp::WarpMetrics) -> PyResult<Bound<'py, PyAny>> {
    let d = PyDict::new(py);
    d.set_item("udim", m.udim)?;
    d.set_item("rigid_texels", m.rigid_texels)?;
    for (prefix, s) in [("stretch_identity", m.stretch_identity), ("stretch_warped", m.stretch_warped)] {
        d.set_item(format!("{prefix}_mean"), s.mean)?;
        d.set_item(format!("{prefix}_p95"), s.p95)?;
        d.set_item(format!("{prefix}_max"), s.max)?;
    }
    d.set_item("foldovers", m.foldovers)?;
    d.set_item("max_masked_displacement", m.max_masked_displacement)?;
    d.set_item("max_displacement", m.max_displacement)?;
    d.set_item("round_trip_max", m.round_trip_max)?;
    d.set_item("round_trip_mean", m.round_trip_mean)?;
    crate::convert::report(py, "WarpMetrics", &d)
}

impl UvWarp {
    fn read(&self) -> std::sync::RwLockReadGuard<'_, warp::UvWarp> {
        self.inner.read().unwrap_or_else(|e| e.into_inner())
    }

    fn write(&self) -> std::sync::RwLockWriteGuard<'_, warp::UvWarp> {
        self.inner.write().unwrap_or_else(|e| e.into_inner())
    }

    /// Checks that the warp has tile `udim` (before a solve, so that a typo
    /// does not cost one).
    fn tile_index(&self, udim: u32) -> PyResult<usize> {
        let inner = self.read();
        inner.tiles.iter().position(|t| t.udim() == udim).ok_or_else(|| {
            TegumentError::new_err(format!(
                "udim: this warp has no UDIM tile {udim}; its tiles are {:?}",
                inner.tiles.iter().map(|t| t.udim()).collect::<Vec<_>>()
            ))
        })
    }

    /// The one result of tile `udim` (`None`: the only tile). In 0.1.0 a
    /// warp over several tiles answered with `{udim: result}` instead: that
    /// is still what `udim=None` gives there, deprecated.
    fn per_tile<'py>(
        &self,
        py: Python<'py>,
        what: &str,
        udim: Option<u32>,
        make: impl Fn(&warp::TileWarp) -> PyResult<Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let inner = self.read();
        match udim {
            Some(u) => match inner.tiles.iter().find(|t| t.udim() == u) {
                Some(t) => make(t),
                None => Err(TegumentError::new_err(format!(
                    "udim: this warp has no UDIM tile {u}; its tiles are {:?}",
                    inner.tiles.iter().map(|t| t.udim()).collect::<Vec<_>>()
                ))),
            },
            None if !self.multi => make(&inner.tiles[0]),
            None => {
                crate::convert::deprecated(
                    py,
                    &format!(
                        "UvWarp.{what} without udim= on a warp over several UDIM tiles returns {{udim: result}}; \
                         this is deprecated and goes away in the next release: pass udim= (one of {:?}) for one tile",
                        inner.tiles.iter().map(|t| t.udim()).collect::<Vec<_>>()
                    ),
                )?;
                let d = PyDict::new(py);
                for t in &inner.tiles {
                    d.set_item(t.udim(), make(t)?)?;
                }
                Ok(d.into_any())
            }
        }
    }
}

#[pymethods]
impl UvWarp {
    #[new]
    #[pyo3(
        signature = (*args, mask=None, shape=None, iterations=WarpSettings::default().iterations as i64, orientation=WarpSettings::default().orientation, smoothing=WarpSettings::default().smoothing, warm_start=WarpSettings::default().warm_start, memory_limit=None, sample_warped=WarpSettings::default().sample_warped),
        text_signature = "(rest_positions, corner_verts, polygon_sizes, corner_uvs, rigidity, /, mask=None, *, shape=None, iterations=..., orientation=..., smoothing=..., warm_start=..., memory_limit=None, sample_warped=...)"
    )]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        args: &Bound<'_, PyTuple>,
        mask: Option<&Bound<'_, PyAny>>,
        shape: Option<(i64, i64)>,
        iterations: i64,
        orientation: f32,
        smoothing: f32,
        warm_start: bool,
        memory_limit: Option<u64>,
        sample_warped: bool,
    ) -> PyResult<Self> {
        let args: Vec<Bound<'_, PyAny>> = args.iter().collect();
        // 0.1.0: UvWarp(width, height, rest_positions, ...), width first
        // although every array is (height, width).
        let old_form = args.first().is_some_and(|a| a.extract::<i64>().is_ok() && !a.is_instance_of::<pyo3::types::PyBool>());
        let (size, args) = if old_form {
            crate::convert::deprecated(
                py,
                "UvWarp(width, height, rest_positions, ...) is deprecated and goes away in the next release: \
                 drop width and height (the grid takes the shape of rigidity), or pass shape=(height, width)",
            )?;
            let height = args.get(1).map(|h| h.extract::<i64>()).transpose()?;
            (Some((height.unwrap_or(0), args[0].extract::<i64>()?)), &args[2.min(args.len())..])
        } else {
            (None, &args[..])
        };
        if !(5..=6).contains(&args.len()) {
            return Err(TegumentError::new_err(format!(
                "UvWarp takes 5 or 6 positional arguments (rest_positions, corner_verts, polygon_sizes, corner_uvs, rigidity, mask); got {}",
                args.len()
            )));
        }
        let mask = match (args.get(5), mask) {
            (Some(_), Some(_)) => return Err(TegumentError::new_err("UvWarp: mask given twice (positionally and as mask=)")),
            (Some(m), None) => Some(m),
            (None, m) => m,
        };
        let (rest_positions, corner_verts, polygon_sizes, corner_uvs, rigidity) = (&args[0], &args[1], &args[2], &args[3], &args[4]);
        if let (Some(a), Some(b)) = (size, shape) {
            if a != b {
                return Err(TegumentError::new_err(format!("UvWarp: shape={b:?} disagrees with width and height ({}, {})", a.1, a.0)));
            }
        }
        let (h, w) = match size.or(shape) {
            Some((h, w)) => (size_arg("height", h)?, size_arg("width", w)?),
            None => {
                let (h, w) = rigidity_shape(rigidity)?;
                (size_arg("height", h)?, size_arg("width", w)?)
            }
        };
        if !(1..=10_000).contains(&iterations) {
            return Err(TegumentError::new_err(format!("iterations must be between 1 and 10000, not {iterations}")));
        }
        let positions = positions_arg("rest_positions", rest_positions, None)?;
        let corner_verts = int_array_arg("corner_verts", corner_verts, None)?;
        let polygon_sizes = int_array_arg("polygon_sizes", polygon_sizes, None)?;
        let (_, uv_flat) = float_grid_arg("corner_uvs", corner_uvs, &[Some(corner_verts.len()), Some(2)]).map_err(|e| {
            TegumentError::new_err(format!("{} (one UV per face corner: the mesh has {} corners)", e.value(py), corner_verts.len()))
        })?;
        let uvs: Vec<Vec2> = uv_flat.chunks(2).map(|c| Vec2::new(c[0], c[1])).collect();
        let rig = tile_images("rigidity", rigidity, w, h)?;
        let masks = match mask {
            Some(m) if !m.is_none() => tile_images("mask", m, w, h)?,
            _ => BTreeMap::new(),
        };
        if let Some(udim) = masks.keys().find(|k| !rig.contains_key(k)) {
            return Err(TegumentError::new_err(format!("mask given for UDIM tile {udim}, which has no rigidity map")));
        }
        let settings = WarpSettings {
            iterations: iterations as u32,
            orientation,
            smoothing,
            warm_start,
            memory_limit: memory_limit.unwrap_or(warp::DEFAULT_MEMORY_LIMIT),
            sample_warped,
        };
        let multi = rig.len() > 1;
        let inner = run_detached(py, || {
            let maps: Vec<TileMaps<'_>> = rig.iter().map(|(&udim, r)| TileMaps { udim, rigidity: r, mask: masks.get(&udim).map(|m| m.as_slice()) }).collect();
            warp::UvWarp::new(
                MeshInput { positions: &positions, corner_verts: &corner_verts, polygon_sizes: &polygon_sizes },
                &uvs,
                w,
                h,
                &maps,
                settings,
            )
        })?;
        Ok(UvWarp { inner: RwLock::new(inner), multi })
    }

    /// Solves the warp of every tile for this frame's ``deformed_positions``
    /// (float32 ``(N, 3)``) and returns the UV redirection of tile ``udim``,
    /// float32 ``(height, width, 2)``: for a surface point whose UV is ``t``,
    /// sample the texture at ``redirection(t)`` (absolute UVs, UDIM offset
    /// included). Other tiles: :meth:`redirection`. Releases the GIL.
    #[pyo3(signature = (deformed_positions, udim=None))]
    fn solve<'py>(&self, py: Python<'py>, deformed_positions: &Bound<'py, PyAny>, udim: Option<u32>) -> PyResult<Bound<'py, PyAny>> {
        let positions = positions_arg("deformed_positions", deformed_positions, Some(self.read().mesh.vertex_count))?;
        if let Some(u) = udim {
            self.tile_index(u)?;
        }
        run_detached(py, || self.write().solve(&positions))?;
        self.per_tile(py, "solve()", udim, |t| Ok(redirection_array(py, t, self.read().width, self.read().height)))
    }

    /// The latest redirection of tile ``udim`` (identity before the first
    /// solve), as :meth:`solve` returns it.
    #[pyo3(signature = (udim=None))]
    fn redirection<'py>(&self, py: Python<'py>, udim: Option<u32>) -> PyResult<Bound<'py, PyAny>> {
        let (w, h) = (self.read().width, self.read().height);
        self.per_tile(py, "redirection()", udim, |t| Ok(redirection_array(py, t, w, h)))
    }

    /// Validity of tile ``udim``, float32 ``(height, width)``: 1 inside UV
    /// charts, 0 outside.
    #[pyo3(signature = (udim=None))]
    fn validity<'py>(&self, py: Python<'py>, udim: Option<u32>) -> PyResult<Bound<'py, PyAny>> {
        let (w, h) = (self.read().width, self.read().height);
        self.per_tile(py, "validity()", udim, |t| {
            Ok(Array2::from_shape_vec((h, w), t.validity().iter().map(|&v| v as f32).collect()).expect("w·h values").into_pyarray(py).into_any())
        })
    }

    /// The forward warp of tile ``udim`` as displacements in texels, float32
    /// ``(height, width, 2)``: the texture detail at texel centre ``t`` is
    /// drawn at ``t + d``.
    #[pyo3(signature = (udim=None))]
    fn displacement<'py>(&self, py: Python<'py>, udim: Option<u32>) -> PyResult<Bound<'py, PyAny>> {
        let (w, h) = (self.read().width, self.read().height);
        self.per_tile(py, "displacement()", udim, |t| {
            let (dx, dy) = t.displacement();
            let flat: Vec<f32> = dx.iter().zip(dy).flat_map(|(&x, &y)| [x, y]).collect();
            Ok(Array3::from_shape_vec((h, w, 2), flat).expect("2·w·h floats").into_pyarray(py).into_any())
        })
    }

    /// Quality figures of tile ``udim`` of the current warp (the last solve)
    /// measured against ``deformed_positions``: a
    /// :class:`tegument.results.WarpMetrics` with the rigid-region stretch
    /// error (mean, p95, max of ``max(|log σ1|, |log σ2|)`` over texels with
    /// rigidity ≥ 0.5) for the identity warp and the solved one, fold-overs,
    /// largest displacement of masked texels, round-trip error in texels.
    /// Releases the GIL.
    #[pyo3(signature = (deformed_positions, udim=None))]
    fn metrics<'py>(&self, py: Python<'py>, deformed_positions: &Bound<'py, PyAny>, udim: Option<u32>) -> PyResult<Bound<'py, PyAny>> {
        let positions = positions_arg("deformed_positions", deformed_positions, Some(self.read().mesh.vertex_count))?;
        if let Some(u) = udim {
            self.tile_index(u)?;
        }
        let all = run_detached(py, || self.read().metrics(&positions))?;
        self.per_tile(py, "metrics()", udim, |t| {
            let m = all.iter().find(|m| m.udim == t.udim()).expect("one figure set per tile");
            metrics_report(py, m)
        })
    }

    /// Forgets the previous frame: the next ``solve`` starts from the identity.
    fn reset(&self) {
        self.write().reset();
    }

    /// Writes the latest redirection of ``udim`` (default: the only tile) to
    /// an OpenEXR file: float32 R, G = redirected UV, B = validity, the
    /// settings as metadata. Atomic (temporary file, then rename).
    #[pyo3(signature = (path, udim=None))]
    fn write_exr(&self, py: Python<'_>, path: PathBuf, udim: Option<u32>) -> PyResult<()> {
        let udim = match udim {
            Some(u) => u,
            None if !self.multi => self.read().tiles[0].udim(),
            None => {
                return Err(TegumentError::new_err(format!(
                    "this warp spans UDIM tiles {:?}: say which one to write (udim=...)",
                    self.read().tiles.iter().map(|t| t.udim()).collect::<Vec<_>>()
                )))
            }
        };
        run_detached(py, || self.read().write_exr(udim, &path))
    }

    /// UDIM tiles the UVs touch, ascending.
    #[getter]
    fn tiles(&self) -> Vec<u32> {
        self.read().tiles.iter().map(|t| t.udim()).collect()
    }

    /// Grid width per tile.
    #[getter]
    fn width(&self) -> usize {
        self.read().width
    }

    /// Grid height per tile.
    #[getter]
    fn height(&self) -> usize {
        self.read().height
    }

    /// Number of UV charts found (edges shared with identical UVs join charts).
    #[getter]
    fn chart_count(&self) -> usize {
        self.read().mesh.chart_count
    }

    /// The settings, as written into EXR metadata.
    fn settings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (k, v) in self.read().settings.describe() {
            d.set_item(k, v)?;
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!("tegument.UvWarp({}×{}, tiles {:?}, {} charts)", self.read().width, self.read().height, self.tiles(), self.read().mesh.chart_count)
    }
}

/// Writes a float32 image ``(height, width)`` or ``(height, width, C)`` with
/// 1 ≤ C ≤ 4 (channels R, G, B, A; row 0 = lowest v, stored top row first as
/// EXR expects) to ``path``, with ``metadata`` (str → str, Latin-1 text,
/// keys of 1 to 246 characters) as attributes. Refuses NaN and infinities;
/// atomic (temporary file, then rename).
#[pyfunction]
#[pyo3(signature = (path, array, metadata=None))]
fn write_exr(py: Python<'_>, path: PathBuf, array: &Bound<'_, PyAny>, metadata: Option<BTreeMap<String, String>>) -> PyResult<()> {
    let (shape, data) = match float_grid_arg("array", array, &[None, None, None]) {
        Ok(v) => v,
        Err(_) => float_grid_arg("array", array, &[None, None])
            .map_err(|_| TegumentError::new_err(format!("array: expected float32 (height, width) or (height, width, channels) (other float types are converted); got {}", array.repr().map(|r| r.to_string()).unwrap_or_default().chars().take(80).collect::<String>())))?,
    };
    let channels = if shape.len() == 3 { shape[2] } else { 1 };
    let meta: Vec<(String, String)> = metadata.unwrap_or_default().into_iter().collect();
    check_metadata(&meta)?;
    run_detached(py, || warp::exr::write_exr(&path, shape[1], shape[0], channels, &data, &meta))
}

/// OpenEXR text attributes hold Latin-1 bytes and names up to 255 bytes
/// ending at the first NUL; anything else would make the writer panic or the
/// file unreadable, so it is refused here with the offending entry named.
fn check_metadata(meta: &[(String, String)]) -> PyResult<()> {
    const PREFIX: usize = "tegument.".len();
    for (key, value) in meta {
        for (what, text) in [("key", key), ("value", value)] {
            if let Some(c) = text.chars().find(|&c| c as u32 > 0xFF || c == '\0') {
                return Err(TegumentError::new_err(format!(
                    "metadata {what} {text:?}: OpenEXR text attributes hold Latin-1 characters only (no NUL); {c:?} is not one"
                )));
            }
        }
        if key.is_empty() || key.chars().count() + PREFIX > 255 {
            return Err(TegumentError::new_err(format!(
                "metadata key {key:?}: must be 1 to {} characters long", 255 - PREFIX
            )));
        }
    }
    Ok(())
}

/// Reads an OpenEXR image: returns ``(array, metadata)`` with ``array``
/// float32 ``(height, width, C)`` (channels R, G, B, A first; row 0 = lowest
/// v) and ``metadata`` the file's text attributes.
#[pyfunction]
fn read_exr<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyAny>, BTreeMap<String, String>)> {
    let (w, h, c, data, meta) = run_detached(py, || warp::exr::read_exr(&path))?;
    let array = Array3::from_shape_vec((h, w, c), data).expect("w·h·c floats").into_pyarray(py).into_any();
    Ok((array, meta.into_iter().collect()))
}

/// A UDIM tile number argument (1001 + u + 10·v, u in [0, 10), v in [0, 1000)).
fn udim_arg(udim: i64) -> PyResult<u32> {
    if !(1001..=11_000).contains(&udim) {
        return Err(TegumentError::new_err(format!("udim must be a UDIM tile number between 1001 and 11000, not {udim}")));
    }
    Ok(udim as u32)
}

/// `corner_uvs` as `(C, 2)` UVs.
fn uvs_arg(obj: &Bound<'_, PyAny>) -> PyResult<Vec<Vec2>> {
    let (_, flat) = float_grid_arg("corner_uvs", obj, &[None, Some(2)])?;
    Ok(flat.chunks(2).map(|c| Vec2::new(c[0], c[1])).collect())
}

/// Interpolates per-corner values (float ``(C,)``, one per face corner)
/// linearly over the fan-triangulated UV polygons and samples them at the
/// texel centres of UDIM tile ``udim``: float32 ``shape = (height, width)``,
/// 0 where no UV triangle covers a texel centre. Turns a vertex group into a
/// rigidity map. Releases the GIL.
#[pyfunction]
#[pyo3(signature = (corner_uvs, polygon_sizes, corner_values, udim, shape))]
fn rasterise_corner_values<'py>(
    py: Python<'py>,
    corner_uvs: &Bound<'py, PyAny>,
    polygon_sizes: &Bound<'py, PyAny>,
    corner_values: &Bound<'py, PyAny>,
    udim: i64,
    shape: (i64, i64),
) -> PyResult<Bound<'py, PyAny>> {
    let uvs = uvs_arg(corner_uvs)?;
    let sizes = int_array_arg("polygon_sizes", polygon_sizes, None)?;
    let values = float_array_arg("corner_values", corner_values, Some(uvs.len()))?;
    let udim = udim_arg(udim)?;
    let (h, w) = (size_arg("height", shape.0)?, size_arg("width", shape.1)?);
    let image = run_detached(py, || warp::images::rasterise_corner_values(&uvs, &sizes, &values, udim, w, h))?;
    Ok(Array2::from_shape_vec((h, w), image).expect("w·h floats").into_pyarray(py).into_any())
}

/// Bilinear resample of an image ``pixels`` (float ``(h, w)``, row 0 at the
/// bottom) to the texel centres of a grid of ``shape = (height, width)``
/// covering the same square; float32. Samples beyond the outer pixel centres
/// take the edge pixels. Releases the GIL.
#[pyfunction]
#[pyo3(signature = (pixels, shape))]
fn resample_image<'py>(py: Python<'py>, pixels: &Bound<'py, PyAny>, shape: (i64, i64)) -> PyResult<Bound<'py, PyAny>> {
    let (src, data) = float_grid_arg("pixels", pixels, &[None, None])?;
    let (h, w) = (size_arg("height", shape.0)?, size_arg("width", shape.1)?);
    let image = run_detached(py, || warp::images::resample_bilinear(&data, src[1], src[0], w, h))?;
    Ok(Array2::from_shape_vec((h, w), image).expect("w·h floats").into_pyarray(py).into_any())
}

/// Per-texel stretch error of texture detail under a warp, float32
/// ``(height, width)`` for UDIM tile ``udim``: ``max(|ln σ1|, |ln σ2|)`` of
/// the detail's deformation gradient from the rest to the deformed surface
/// (the measure :meth:`UvWarp.metrics` aggregates), 0 outside the UV charts,
/// capped at 34.5 where the warp folds or collapses. ``displacement`` is the
/// tile's float ``(height, width, 2)`` displacement in texels
/// (:meth:`UvWarp.displacement`) and sets the grid size. Releases the GIL.
#[pyfunction]
#[pyo3(signature = (rest_positions, deformed_positions, corner_verts, polygon_sizes, corner_uvs, displacement, udim=None))]
#[allow(clippy::too_many_arguments)]
fn stretch_map<'py>(
    py: Python<'py>,
    rest_positions: &Bound<'py, PyAny>,
    deformed_positions: &Bound<'py, PyAny>,
    corner_verts: &Bound<'py, PyAny>,
    polygon_sizes: &Bound<'py, PyAny>,
    corner_uvs: &Bound<'py, PyAny>,
    displacement: &Bound<'py, PyAny>,
    udim: Option<i64>,
) -> PyResult<Bound<'py, PyAny>> {
    let rest = positions_arg("rest_positions", rest_positions, None)?;
    let deformed = positions_arg("deformed_positions", deformed_positions, Some(rest.len()))?;
    let corner_verts = int_array_arg("corner_verts", corner_verts, None)?;
    let polygon_sizes = int_array_arg("polygon_sizes", polygon_sizes, None)?;
    let uvs = uvs_arg(corner_uvs)?;
    let (shape, disp) = float_grid_arg("displacement", displacement, &[None, None, Some(2)])?;
    let udim = udim_arg(udim.unwrap_or(1001))?;
    let (h, w) = (shape[0], shape[1]);
    let image = run_detached(py, || {
        warp::images::stretch_map(&warp::images::StretchInput {
            rest: &rest,
            deformed: &deformed,
            corner_verts: &corner_verts,
            polygon_sizes: &polygon_sizes,
            corner_uvs: &uvs,
            udim,
            width: w,
            height: h,
            displacement: &disp,
        })
    })?;
    Ok(Array2::from_shape_vec((h, w), image).expect("w·h floats").into_pyarray(py).into_any())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<UvWarp>()?;
    m.add_function(wrap_pyfunction!(write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    m.add_function(wrap_pyfunction!(rasterise_corner_values, m)?)?;
    m.add_function(wrap_pyfunction!(resample_image, m)?)?;
    m.add_function(wrap_pyfunction!(stretch_map, m)?)?;
    Ok(())
}
