//! `tegument.PyramidDeformer`: bind a rest mesh, solve deformed frames.

use std::sync::Mutex;

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyUntypedArray};
use pyo3::prelude::*;
use tegument_core::mesh::MeshInput;
use pyo3::types::PyDict;
use tegument_core::collide::{AuditParams, ColliderSettings, SelfSettings};
use tegument_core::warp::WarpSettings;
use tegument_core::collide::Collider as CoreCollider;
use tegument_core::pyramid::{Closeness, DeformerOptions, PinReason};
use tegument_core::sequence::{
    Dynamics as CoreDynamics, SelfOptions, Sequence as Core, StepOptions, StepReport, StrainMode, StrainOptions,
};
use tegument_core::strain::MaxStretch;

use crate::collide::collider_refs;

use crate::convert::{
    copy_positions_to, float_array_arg, indices_to_py, int_array_arg, out_or_new, points_into, positions_arg, positions_to_py,
    py_result, run_detached, TegumentError,
};
use tegument_core::mesh::validate_positions;

/// Pyramid-coordinate deformer: keeps the local shape of the rest mesh on top
/// of whatever deformation the input positions carry (armature, shape keys).
///
/// ``rest_positions`` float32 ``(N, 3)``, ``corner_verts`` int32 ``(L,)`` and
/// ``polygon_sizes`` int32 ``(P,)`` describe the mesh at rest in Blender's
/// layout. ``scale_safe`` stores edge elevation angles instead of plain heights,
/// so that a uniformly scaled input is reproduced exactly. Vertices that
/// coincide at rest (split seams of imported meshes) are welded for the
/// solver, so seams stay closed; the mesh arrays themselves are only read.
/// Open borders are encoded with open one-rings; corners, non-manifold and
/// degenerate spots that cannot be encoded follow the input and are listed in
/// ``pinned_vertices``. Raises ``TegumentError`` on bad input.
#[pyclass(module = "tegument", name = "PyramidDeformer", frozen)]
pub struct PyramidDeformer {
    // A mutex rather than `&mut self`: solves run without the GIL, and another
    // Python thread calling in meanwhile waits instead of getting an error.
    inner: Mutex<Core>,
    vertex_count: usize,
    last_step: Mutex<Option<StepReport>>,
    /// The last frame's input, kept for its allocation: see [`points_into`].
    input: Mutex<Vec<glam::Vec3>>,
    /// The last :meth:`solve`'s input and result, where a warm solve starts from.
    solved: Mutex<Option<(Vec<glam::Vec3>, Vec<glam::Vec3>)>>,
}

impl PyramidDeformer {
    /// The arguments every frame takes: the input positions (read into the
    /// buffer the last frame used; give it back with [`Self::keep_input`]), the
    /// iteration count and the closeness, checked against this deformer.
    fn frame_args(
        &self,
        positions: &Bound<'_, PyAny>,
        iterations: i64,
        closeness: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<(Vec<glam::Vec3>, usize, Weights)> {
        let n = self.vertex_count;
        let mut input = std::mem::take(&mut *self.input.lock().unwrap_or_else(|e| e.into_inner()));
        points_into("positions", positions, Some(n), &mut input)?;
        py_result(validate_positions("positions", &input))?;
        if iterations < 0 {
            return Err(TegumentError::new_err(format!("iterations is {iterations}; it must be 0 or more")));
        }
        Ok((input, iterations as usize, closeness_arg(closeness, n)?))
    }

    fn keep_input(&self, input: Vec<glam::Vec3>) {
        *self.input.lock().unwrap_or_else(|e| e.into_inner()) = input;
    }


    fn with<T: Send>(&self, py: Python<'_>, work: impl FnOnce(&mut Core) -> tegument_core::Result<T> + Send) -> PyResult<T> {
        run_detached(py, || {
            let mut core = self
                .inner
                .lock()
                .map_err(|_| tegument_core::Error::Numerical("an earlier call on this deformer failed mid-way; bind again".into()))?;
            work(&mut core)
        })
    }
}

#[pymethods]
impl PyramidDeformer {
    #[new]
    #[pyo3(signature = (rest_positions, corner_verts, polygon_sizes, scale_safe = DeformerOptions::default().scale_safe))]
    fn new(
        py: Python<'_>,
        rest_positions: &Bound<'_, PyAny>,
        corner_verts: &Bound<'_, PyAny>,
        polygon_sizes: &Bound<'_, PyAny>,
        scale_safe: bool,
    ) -> PyResult<Self> {
        let positions = positions_arg("rest_positions", rest_positions, None)?;
        let corner_verts = int_array_arg("corner_verts", corner_verts, None)?;
        let polygon_sizes = int_array_arg("polygon_sizes", polygon_sizes, None)?;
        let core = run_detached(py, || {
            Core::bind(
                MeshInput { positions: &positions, corner_verts: &corner_verts, polygon_sizes: &polygon_sizes },
                DeformerOptions { scale_safe, ..DeformerOptions::default() },
            )
        })?;
        Ok(PyramidDeformer {
            vertex_count: core.vertex_count(),
            inner: Mutex::new(core),
            last_step: Mutex::new(None),
            solved: Mutex::new(None),
            input: Mutex::new(Vec::new()),
        })
    }

    /// Number of vertices of the bound mesh.
    #[getter]
    fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    /// Whether the solver is accelerated (``False`` by default): every
    /// iteration then also corrects the smooth part of the error on coarser
    /// levels of the mesh (multigrid, with Chebyshev extrapolation), so that 6 iterations get within 5 % of
    /// the converged solution of the same settings, where plain iterations
    /// need hundreds at low closeness. An iteration costs about two and a
    /// half plain ones at 100k vertices. Same solution either way. With a
    /// :attr:`tolerance` and warm solves, frames that follow each other take
    /// 2–4 iterations.
    #[getter]
    fn accelerated(&self, py: Python<'_>) -> PyResult<bool> {
        self.with(py, |core| Ok(core.deformer_mut().accelerated()))
    }

    #[setter]
    fn set_accelerated(&self, py: Python<'_>, on: bool) -> PyResult<()> {
        self.with(py, |core| {
            core.deformer_mut().set_accelerated(on);
            Ok(())
        })
    }

    /// When an accelerated solve may stop before its iteration count
    /// (``None`` by default: it runs them all): once its estimated
    /// convergence error, the distance left to the converged solution, is at
    /// most this fraction of the displacement (RMS over the vertices; offsets
    /// below a tenth of an edge count as that much). The count becomes a
    /// limit; :attr:`last_iterations` says how many ran. Plain iterations
    /// always run their count; a :meth:`step` with colliders or strain limits
    /// stops after an iteration whose contact passes have run.
    /// ``tegument.DEFAULTS.tolerance`` is the add-on's Converge setting.
    #[getter]
    fn tolerance(&self, py: Python<'_>) -> PyResult<Option<f32>> {
        self.with(py, |core| Ok(core.deformer_mut().tolerance()))
    }

    #[setter]
    fn set_tolerance(&self, py: Python<'_>, tolerance: Option<f32>) -> PyResult<()> {
        self.with(py, |core| core.deformer_mut().set_tolerance(tolerance))
    }

    /// Iterations the last solve ran: its count, or fewer with a :attr:`tolerance`.
    #[getter]
    fn last_iterations(&self, py: Python<'_>) -> PyResult<usize> {
        self.with(py, |core| Ok(core.deformer_mut().last_iterations()))
    }

    /// Number of vertices the solver works on: the mesh's, with vertices
    /// that coincide at rest (split UV or sharp-normal seams, as glTF, FBX and
    /// USD importers deliver them) welded into one. Results come back per
    /// mesh vertex, the same position for every member of a seam.
    #[getter]
    fn welded_vertex_count(&self, py: Python<'_>) -> PyResult<usize> {
        self.with(py, |core| Ok(core.welded_vertex_count()))
    }

    /// int32 ``(K,)``: the vertices the bind could not encode (boundary,
    /// non-manifold, degenerate or very high valence one-rings), ascending.
    /// They follow the input positions exactly.
    #[getter]
    fn pinned_vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<i32>>> {
        let pinned = self.with(py, |core| Ok(core.pinned_vertices()))?;
        Ok(indices_to_py(py, &pinned))
    }

    /// ``{reason: int32 (K,)}``: the pinned vertices by why the bind could not
    /// encode them, each array ascending; only reasons that occur are keys.
    /// Reasons: ``boundary`` (a border corner without a usable one-ring),
    /// ``non_manifold``, ``isolated``, ``low_valence`` (fewer than 3
    /// neighbours), ``high_valence``, ``zero_area`` (a one-ring without
    /// area), ``not_star_shaped`` (the vertex does not project inside its
    /// ring), ``inexact`` (not reproducible in single precision). Together
    /// they hold exactly ``pinned_vertices``.
    #[getter]
    fn pinned_reasons<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let pinned = self.with(py, |core| Ok(core.pinned()))?;
        let dict = PyDict::new(py);
        for reason in PinReason::ALL {
            let mut vertices: Vec<u32> = pinned.iter().filter(|&&(_, r)| r == reason).map(|&(v, _)| v).collect();
            if !vertices.is_empty() {
                vertices.sort_unstable();
                dict.set_item(reason.name(), indices_to_py(py, &vertices))?;
            }
        }
        Ok(dict)
    }

    /// Solves one frame and returns float32 ``(N, 3)`` positions: ``out`` if
    /// given (a float32 ``(N, 3)`` C-contiguous array, reused frame after
    /// frame to spare a large allocation), else a new array.
    ///
    /// ``positions`` is the deformed input, float32 ``(N, 3)``. ``closeness``
    /// pulls each vertex towards its input: ``None`` (the default weight,
    /// ``tegument.DEFAULTS.closeness``: 0.05; it was 0.1 in 0.1.0), a float in
    /// ``[0, 1]``, or a float32 ``(N,)`` array of per-vertex
    /// weights in ``[0, 1]`` (1 = follow the input exactly, 0 = keep only the
    /// local shape). Deterministic whatever the thread count.
    ///
    /// With ``warm`` the solve starts from the last :meth:`solve`'s result
    /// moved as the input moved (its offset from its input, added to this
    /// input) instead of from the input: the same solution, reached in fewer
    /// iterations when frames follow each other, which :attr:`tolerance`
    /// turns into time. The first solve, and the first after :meth:`reset`
    /// or a failed one, start from the input.
    #[pyo3(signature = (positions, iterations = StepOptions::default().iterations as i64, closeness = None, *, out = None, warm = false))]
    fn solve<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        iterations: i64,
        closeness: Option<&Bound<'py, PyAny>>,
        out: Option<&Bound<'py, PyAny>>,
        warm: bool,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let (input, iterations, weights) = self.frame_args(positions, iterations, closeness)?;
        let output = out_or_new(py, out, self.vertex_count)?;
        // Taken out, not held: the lock must not be held while the solve
        // runs without the GIL (another thread could hold the GIL and wait on it).
        let last = self.solved.lock().unwrap_or_else(|e| e.into_inner()).take();
        // The solve runs in the returned array itself: no result vector to
        // copy out at 100k+ vertices per frame.
        {
            let mut writable = output.readwrite();
            let flat = writable.as_slice_mut().expect("C-contiguous: made here or checked by out_arg");
            let out: &mut [glam::Vec3] = bytemuck::cast_slice_mut(flat);
            match last.as_ref().filter(|_| warm) {
                // The last result moved as the input moved.
                Some((last_input, last_result)) => {
                    for (((o, i), r), l) in out.iter_mut().zip(&input).zip(last_result).zip(last_input) {
                        *o = *i + (*r - *l);
                    }
                }
                None => out.copy_from_slice(&input),
            }
            let input = &input;
            self.with(py, move |core| core.solve_into(input, out, iterations, weights.as_closeness(), None))?;
        }
        // Remember this solve for the next warm one; the older input's
        // allocation serves the next frame's.
        let (spare, mut result) = last.unwrap_or_default();
        result.clear();
        result.extend_from_slice(bytemuck::cast_slice(output.readonly().as_slice().expect("C-contiguous")));
        *self.solved.lock().unwrap_or_else(|e| e.into_inner()) = Some((input, result));
        self.keep_input(spare);
        Ok(output)
    }

    /// Solves the next frame of an animation against ``colliders`` and
    /// returns float32 ``(N, 3)`` positions.
    ///
    /// History-based (seed 000, Algorithm 2): the deformer keeps its last
    /// output, which is free of collisions. Each vertex first moves from there
    /// towards this frame's ``positions`` while the colliders (a sequence of
    /// :class:`Collider`, already :meth:`Collider.update`-d to this frame)
    /// sweep from their previous to their current positions, stopping at
    /// contacts with friction; then the solve runs, and after every iteration
    /// contacts along each vertex's move are detected and resolved again.
    /// The first call, and the first after :meth:`reset`, starts from
    /// ``positions`` itself; without colliders and dynamics, every later
    /// call starts its solve from the last output moved as the input moved
    /// (a warm start: same solution, reached in fewer iterations), where
    /// :meth:`solve` always starts from the input. Vertices squeezed between colliders are pinched:
    /// kept near the solve's result, never NaN, and listed in
    /// :attr:`last_step`. ``iterations`` and ``closeness`` as in :meth:`solve`.
    ///
    /// ``substeps`` (1–64) splits the frame, the input and the colliders
    /// interpolated linearly. ``dynamics`` (a :class:`Dynamics`) adds inertia:
    /// the closeness becomes the goal strength (1 follows the input exactly,
    /// low values jiggle). ``max_stretch`` limits every edge to
    /// ``(1 + ε)`` times its rest length: ``None`` (no limit), a float ε ≥ 0,
    /// or a float32 ``(N,)`` array of per-vertex ε (``inf`` = no limit; an edge
    /// takes the mean of its ends). ``strain_mode`` is ``"unified"`` (limits
    /// and contacts in the same loop, until both hold) or ``"post"`` (limits
    /// after the collision passes; can leave penetrations). Colliders with
    /// compliance (:meth:`Collider.set_compliance`) are solved too: their
    /// :attr:`Collider.positions` become where they receded.
    /// ``self_collision`` (a :class:`SelfCollision`) keeps the skin from
    /// passing through itself, in the same two passes and together with the
    /// colliders: the output has no self-intersection its history did not
    /// have; what the input brings in intersecting is left to come apart and
    /// counted in :attr:`last_step`. ``out`` as in :meth:`solve`.
    #[pyo3(signature = (positions, colliders = None, iterations = StepOptions::default().iterations as i64, closeness = None, substeps = StepOptions::default().substeps as i64, dynamics = None, max_stretch = None, strain_mode = StrainMode::default().name(), *, out = None, self_collision = None))]
    #[allow(clippy::too_many_arguments)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        colliders: Option<&Bound<'py, PyAny>>,
        iterations: i64,
        closeness: Option<&Bound<'py, PyAny>>,
        substeps: i64,
        dynamics: Option<PyRef<'py, Dynamics>>,
        max_stretch: Option<&Bound<'py, PyAny>>,
        strain_mode: &str,
        out: Option<&Bound<'py, PyAny>>,
        self_collision: Option<PyRef<'py, SelfCollision>>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let (input, iterations, weights) = self.frame_args(positions, iterations, closeness)?;
        let self_settings = self_collision.as_ref().map(|s| s.inner);
        let self_weights = match self_collision.as_ref().and_then(|s| s.weights.as_ref()) {
            Some(w) if w.len() != self.vertex_count => {
                return Err(TegumentError::new_err(format!(
                    "self_collision: its weights have {} values, the deformer has {} vertices",
                    w.len(),
                    self.vertex_count
                )))
            }
            other => other.cloned(),
        };
        let output = out_or_new(py, out, self.vertex_count)?;
        if substeps < 1 {
            return Err(TegumentError::new_err(format!("substeps is {substeps}; it must be between 1 and {}", tegument_core::sequence::MAX_SUBSTEPS)));
        }
        let mode = match strain_mode {
            "unified" => StrainMode::Unified,
            "post" => StrainMode::Post,
            other => return Err(TegumentError::new_err(format!("strain_mode is {other:?}; expected \"unified\" or \"post\""))),
        };
        let stretch = max_stretch_arg(max_stretch, self.vertex_count)?;
        let dynamics = dynamics.map(|d| d.inner);
        let refs = match colliders {
            Some(c) => collider_refs(c)?,
            None => Vec::new(),
        };
        let holders: Vec<&crate::collide::Collider> = refs.iter().map(|r| &**r).collect();
        // Each collider is locked for writing once: the same one twice would wait on itself.
        for (i, c) in holders.iter().enumerate() {
            if holders[..i].iter().any(|o| std::ptr::eq(*o, *c)) {
                return Err(TegumentError::new_err(format!("colliders: item {i} is the same Collider as an earlier one; pass each collider once")));
            }
        }
        let input_ref = &input;
        let (solved, report) = self.with(py, move |core| {
            // Write locks: compliant colliders are solved by the step.
            let mut guards: Vec<_> = holders.iter().map(|c| c.write()).collect();
            let mut cols: Vec<&mut CoreCollider> = guards.iter_mut().map(|g| &mut **g).collect();
            let options = StepOptions {
                substeps: substeps as usize,
                dynamics,
                strain: stretch.as_ref().map(|s| StrainOptions { max_stretch: s.as_max_stretch(), mode }),
                self_collision: self_settings.map(|settings| SelfOptions { settings, weights: self_weights.as_deref() }),
                ..StepOptions::new(iterations, weights.as_closeness())
            };
            core.step(input_ref, &mut cols, &options)
        })?;
        self.keep_input(input);
        *self.last_step.lock().unwrap_or_else(|e| e.into_inner()) = Some(report);
        copy_positions_to(&output, &solved);
        Ok(output)
    }

    /// Velocities at the end of the last dynamic :meth:`step`, float32
    /// ``(N, 3)`` in units per second, or ``None``.
    #[getter]
    fn velocity<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f32>>>> {
        let velocity = self.with(py, |core| Ok(core.velocity()))?;
        Ok(velocity.map(|v| positions_to_py(py, &v)))
    }

    /// Forgets the last output of :meth:`step` and :meth:`solve`: the next
    /// step, and the next warm solve, start from their input. With ``history`` (float32 ``(N, 3)``, free of collisions), the
    /// next step starts from there instead, as if a step had produced it: how
    /// a bake resumes after frames it has already cached. With ``input`` too
    /// (float32 ``(N, 3)``: what ``history`` was solved from), the next warm
    /// :meth:`solve` starts from ``history`` moved as the input moved, as if
    /// a solve of ``input`` had returned it: how a Converge bake resumes, so
    /// that it writes the frames one bake of the whole range writes.
    #[pyo3(signature = (history = None, *, input = None))]
    fn reset(&self, py: Python<'_>, history: Option<&Bound<'_, PyAny>>, input: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let history = history.map(|h| positions_arg("history", h, Some(self.vertex_count))).transpose()?;
        let input = input.map(|i| positions_arg("input", i, Some(self.vertex_count))).transpose()?;
        let solved = match (&history, input) {
            (Some(history), Some(input)) => Some((input, history.clone())),
            (None, Some(_)) => {
                return Err(TegumentError::new_err(
                    "reset: input given without history; pass the result it was solved into as history",
                ))
            }
            _ => None,
        };
        *self.last_step.lock().unwrap_or_else(|e| e.into_inner()) = None;
        *self.solved.lock().unwrap_or_else(|e| e.into_inner()) = solved;
        self.with(py, move |core| match &history {
            Some(h) => core.set_history(h),
            None => {
                core.reset();
                Ok(())
            }
        })
    }

    /// What the last :meth:`step` did, or ``None``: a
    /// :class:`tegument.results.StepReport` with ``first_pass_contacts`` (vertex, edge and collider-vertex contacts of
    /// the first pass), ``first_pass_moved`` (vertices it moved),
    /// ``in_loop_contacts`` (over all iterations), ``max_in_loop_correction``,
    /// ``pinched`` (int32 array of the vertices left pinched),
    /// ``kinetic_energy`` (0 without dynamics), ``worst_stretch`` (largest
    /// length / rest length of a limited edge; 0 without limits),
    /// ``compliant_contacts`` (contacts that stopped compliant collider
    /// vertices), ``compliant_skin_vertices`` (skin vertices giving way to
    /// compliant colliders) and ``max_recession`` (largest distance of a
    /// compliant collider vertex from its animated position), ``held``
    /// (times a pass put a vertex it could not clear of colliders standing
    /// still back where the pass started: a contact that holds, not a pinch),
    /// and with self-collision ``self_contacts`` (contacts between skin and
    /// skin projected), ``self_held`` (times the fail-safe put a vertex back
    /// where its pass started), ``self_pinched`` (int32 array of vertices left
    /// crossing skin where a sweeping collider had the last word),
    /// ``self_intersections`` (pairs of the skin's polygons intersecting in
    /// the output under some split of their quads, neighbours not counted:
    /// what the input brought in that has not come apart yet) and ``self_tangled`` (vertices exempt at the start
    /// of the frame because their triangles intersected there).
    #[getter]
    fn last_step<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let guard = self.last_step.lock().unwrap_or_else(|e| e.into_inner());
        let Some(report) = guard.as_ref() else { return Ok(None) };
        let first = &report.first_pass;
        let dict = PyDict::new(py);
        dict.set_item("first_pass_contacts", first.vertex_contacts + first.edge_contacts + first.collider_vertex_contacts)?;
        dict.set_item("first_pass_moved", first.moved.len())?;
        dict.set_item("in_loop_contacts", report.in_loop_contacts)?;
        dict.set_item("max_in_loop_correction", report.max_in_loop_correction)?;
        dict.set_item("pinched", indices_to_py(py, &report.pinched))?;
        dict.set_item("kinetic_energy", report.kinetic_energy)?;
        dict.set_item("worst_stretch", report.worst_stretch)?;
        dict.set_item("compliant_contacts", report.compliant_contacts)?;
        dict.set_item("compliant_skin_vertices", report.compliant_skin_vertices)?;
        dict.set_item("max_recession", report.max_recession)?;
        dict.set_item("held", report.held)?;
        dict.set_item("self_contacts", report.self_contacts)?;
        dict.set_item("self_held", report.self_held)?;
        dict.set_item("self_pinched", indices_to_py(py, &report.self_pinched))?;
        dict.set_item("self_intersections", report.self_intersections)?;
        dict.set_item("self_tangled", report.self_tangled)?;
        Ok(Some(crate::convert::report(py, "StepReport", &dict)?))
    }

    /// Mean pyramid residual of ``positions`` (float32 ``(N, 3)``): the mean
    /// distance of each encoded vertex from where its one-ring puts it,
    /// relative to the mean rest edge length. 0 at rest and under rigid motion.
    fn residual(&self, py: Python<'_>, positions: &Bound<'_, PyAny>) -> PyResult<f64> {
        let positions = positions_arg("positions", positions, Some(self.vertex_count))?;
        Ok(self.with(py, move |core| core.residual(&positions))? as f64)
    }

    fn __repr__(&self) -> String {
        format!("tegument.PyramidDeformer({} vertices)", self.vertex_count)
    }
}

enum Weights {
    Default,
    Uniform(f32),
    PerVertex(Vec<f32>),
}

impl Weights {
    fn as_closeness(&self) -> Closeness<'_> {
        match self {
            Weights::Default => Closeness::Default,
            Weights::Uniform(c) => Closeness::Uniform(*c),
            Weights::PerVertex(w) => Closeness::PerVertex(w),
        }
    }
}

/// The ``closeness`` argument: ``None``, a float, or a float32 ``(N,)`` array.
fn closeness_arg(closeness: Option<&Bound<'_, PyAny>>, n: usize) -> PyResult<Weights> {
    Ok(match closeness {
        None => Weights::Default,
        Some(obj) if obj.cast::<PyUntypedArray>().is_ok() => Weights::PerVertex(float_array_arg("closeness", obj, Some(n))?),
        Some(obj) if obj.is_instance_of::<pyo3::types::PyBool>() => {
            return Err(TegumentError::new_err("closeness: expected None, a float or a float32 (N,) array; got a bool"))
        }
        Some(obj) => match obj.extract::<f64>() {
            Ok(c) => Weights::Uniform(c as f32),
            Err(_) => {
                let kind = obj.get_type().name().map(|s| s.to_string()).unwrap_or_default();
                return Err(TegumentError::new_err(format!(
                    "closeness: expected None, a float or a float32 ({n},) array; got a {kind}"
                )));
            }
        },
    })
}

/// The ``max_stretch`` argument, owned.
enum Stretch {
    Uniform(f32),
    PerVertex(Vec<f32>),
}

impl Stretch {
    fn as_max_stretch(&self) -> MaxStretch<'_> {
        match self {
            Stretch::Uniform(e) => MaxStretch::Uniform(*e),
            Stretch::PerVertex(e) => MaxStretch::PerVertex(e),
        }
    }
}

/// ``max_stretch``: ``None``, a float, or a float32 ``(N,)`` array.
fn max_stretch_arg(obj: Option<&Bound<'_, PyAny>>, n: usize) -> PyResult<Option<Stretch>> {
    Ok(match obj {
        None => None,
        Some(obj) if obj.cast::<PyUntypedArray>().is_ok() => Some(Stretch::PerVertex(float_array_arg("max_stretch", obj, Some(n))?)),
        Some(obj) if obj.is_instance_of::<pyo3::types::PyBool>() => {
            return Err(TegumentError::new_err("max_stretch: expected None, a float or a float32 (N,) array; got a bool"))
        }
        Some(obj) => match obj.extract::<f64>() {
            Ok(e) => Some(Stretch::Uniform(e as f32)),
            Err(_) => {
                let kind = obj.get_type().name().map(|s| s.to_string()).unwrap_or_default();
                return Err(TegumentError::new_err(format!("max_stretch: expected None, a float or a float32 ({n},) array; got a {kind}")));
            }
        },
    })
}

/// Dynamics settings for :meth:`PyramidDeformer.step` (projective dynamics).
///
/// ``frame_time`` is the length of one frame in seconds (1 / the frame
/// rate); ``mass`` the surface density (vertex masses are density × the
/// vertex's area); ``damping`` the rate (1/s) at which velocity decays;
/// ``gravity`` an acceleration ``(x, y, z)`` in world units per second²
/// (off by default); defaults in ``tegument.DEFAULTS``. With closeness 0.1
/// and mass 1, flesh swings at about 1.7 Hz; higher mass or lower closeness swing slower and further.
#[pyclass(module = "tegument", name = "Dynamics", frozen)]
pub struct Dynamics {
    inner: CoreDynamics,
}

#[pymethods]
impl Dynamics {
    #[new]
    #[pyo3(signature = (frame_time = CoreDynamics::default().frame_time, mass = CoreDynamics::default().mass, damping = CoreDynamics::default().damping, gravity = CoreDynamics::default().gravity.into()))]
    fn new(frame_time: f32, mass: f32, damping: f32, gravity: (f32, f32, f32)) -> PyResult<Self> {
        let inner = CoreDynamics { frame_time, mass, damping, gravity: glam::Vec3::new(gravity.0, gravity.1, gravity.2) };
        crate::convert::py_result(inner.validate())?;
        Ok(Dynamics { inner })
    }

    /// Length of one frame in seconds.
    #[getter]
    fn frame_time(&self) -> f32 {
        self.inner.frame_time
    }

    /// Surface density.
    #[getter]
    fn mass(&self) -> f32 {
        self.inner.mass
    }

    /// Velocity decay rate (1/s).
    #[getter]
    fn damping(&self) -> f32 {
        self.inner.damping
    }

    /// Acceleration ``(x, y, z)``.
    #[getter]
    fn gravity(&self) -> (f32, f32, f32) {
        self.inner.gravity.into()
    }

    fn __repr__(&self) -> String {
        let d = &self.inner;
        format!(
            "tegument.Dynamics(frame_time={}, mass={}, damping={}, gravity=({}, {}, {}))",
            d.frame_time, d.mass, d.damping, d.gravity.x, d.gravity.y, d.gravity.z
        )
    }
}

/// Self-collision settings for :meth:`PyramidDeformer.step`.
///
/// ``thickness`` is the distance kept between skin that folds onto itself
/// (scene units; pairs already closer at rest keep their rest distance);
/// ``friction`` the static friction between the two sides (and the kinetic
/// one unless ``kinetic_friction`` is given); ``rings`` the neighbours left
/// out besides elements sharing a vertex (0: none; ``k``: elements within
/// ``k`` edges, which hides folds sharper than that); ``weights`` None
/// (everywhere) or float32 ``(N,)`` per vertex: only triangles with a corner
/// weighted above 0 take part (e.g. a group over the armpits and elbows).
/// Defaults in ``tegument.DEFAULTS`` (``self_thickness``, ...).
#[pyclass(module = "tegument", name = "SelfCollision", frozen)]
pub struct SelfCollision {
    inner: SelfSettings,
    weights: Option<Vec<f32>>,
}

#[pymethods]
impl SelfCollision {
    #[new]
    #[pyo3(signature = (thickness = SelfSettings::default().thickness, friction = None, kinetic_friction = None, rings = SelfSettings::default().rings as i64, weights = None))]
    fn new(thickness: f32, friction: Option<f32>, kinetic_friction: Option<f32>, rings: i64, weights: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let default = SelfSettings::default();
        let static_friction = friction.unwrap_or(default.static_friction);
        let kinetic_friction = match (friction, kinetic_friction) {
            (_, Some(kinetic)) => kinetic,
            (Some(given), None) => given,
            (None, None) => default.kinetic_friction,
        };
        if rings < 0 {
            return Err(TegumentError::new_err(format!("self-collision rings is {rings}; it must be 0 or more")));
        }
        let inner = SelfSettings { thickness, static_friction, kinetic_friction, rings: rings.min(u32::MAX as i64) as u32 };
        py_result(inner.validate())?;
        let weights = weights.map(|w| float_array_arg("weights", w, None)).transpose()?;
        if let Some(w) = &weights {
            if let Some(v) = w.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
                return Err(TegumentError::new_err(format!("weights: vertex {v} has {}; weights must be finite and ≥ 0", w[v])));
            }
        }
        Ok(SelfCollision { inner, weights })
    }

    /// Distance kept between skin that folds onto itself.
    #[getter]
    fn thickness(&self) -> f32 {
        self.inner.thickness
    }

    /// Static friction coefficient.
    #[getter]
    fn friction(&self) -> f32 {
        self.inner.static_friction
    }

    /// Kinetic friction coefficient.
    #[getter]
    fn kinetic_friction(&self) -> f32 {
        self.inner.kinetic_friction
    }

    /// Rings of neighbours left out besides elements sharing a vertex.
    #[getter]
    fn rings(&self) -> u32 {
        self.inner.rings
    }

    /// The per-vertex weights (float32 ``(N,)``), or None.
    #[getter]
    fn weights<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f32>>> {
        self.weights.as_ref().map(|w| PyArray1::from_slice(py, w))
    }

    fn __repr__(&self) -> String {
        let s = &self.inner;
        let weights = self.weights.as_ref().map_or("None".to_string(), |w| format!("<{} values>", w.len()));
        format!(
            "tegument.SelfCollision(thickness={}, friction={}, kinetic_friction={}, rings={}, weights={weights})",
            s.thickness, s.static_friction, s.kinetic_friction, s.rings
        )
    }
}

/// The default of every setting, from the core's `Default` impls: the
/// fields of `tegument.results.Defaults` (the package exposes them as
/// `tegument.DEFAULTS`). The keyword defaults of the bindings and the
/// add-on's property defaults are these same values.
#[pyfunction]
fn _defaults<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let step = StepOptions::default();
    let dynamics = CoreDynamics::default();
    let collider = ColliderSettings::default();
    let self_settings = SelfSettings::default();
    let warp = WarpSettings::default();
    d.set_item("iterations", step.iterations)?;
    d.set_item("converge", tegument_core::pyramid::DEFAULT_CONVERGE)?;
    d.set_item("accelerated_iterations", tegument_core::pyramid::ACCELERATED_ITERATIONS)?;
    d.set_item("tolerance", decimal(tegument_core::pyramid::CONVERGE_TOLERANCE))?;
    d.set_item("closeness", decimal(tegument_core::pyramid::DEFAULT_CLOSENESS))?;
    d.set_item("substeps", step.substeps)?;
    d.set_item("scale_safe", DeformerOptions::default().scale_safe)?;
    d.set_item("strain_mode", StrainMode::default().name())?;
    d.set_item("frame_time", decimal(dynamics.frame_time))?;
    d.set_item("mass", decimal(dynamics.mass))?;
    d.set_item("damping", decimal(dynamics.damping))?;
    d.set_item("gravity", (decimal(dynamics.gravity.x), decimal(dynamics.gravity.y), decimal(dynamics.gravity.z)))?;
    d.set_item("thickness", decimal(collider.thickness))?;
    d.set_item("friction", decimal(collider.static_friction))?;
    d.set_item("kinetic_friction", decimal(collider.kinetic_friction))?;
    d.set_item("depth_tolerance", decimal(AuditParams::default().depth_tolerance))?;
    d.set_item("self_thickness", decimal(self_settings.thickness))?;
    d.set_item("self_friction", decimal(self_settings.static_friction))?;
    d.set_item("self_kinetic_friction", decimal(self_settings.kinetic_friction))?;
    d.set_item("self_rings", self_settings.rings)?;
    d.set_item("warp_iterations", warp.iterations)?;
    d.set_item("orientation", decimal(warp.orientation))?;
    d.set_item("smoothing", decimal(warp.smoothing))?;
    d.set_item("warm_start", warp.warm_start)?;
    d.set_item("memory_limit", warp.memory_limit)?;
    d.set_item("sample_warped", warp.sample_warped)?;
    Ok(d)
}

/// An f32 setting as the f64 Python shows with the same shortest decimal
/// (0.05, not 0.05000000074505806); it rounds back to the same f32.
fn decimal(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(x as f64)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(_defaults, m)?)?;
    m.add_class::<PyramidDeformer>()?;
    m.add_class::<Dynamics>()?;
    m.add_class::<SelfCollision>()
}
