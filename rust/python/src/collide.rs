//! `tegument.Collider` and `tegument.audit`: kinematic colliders and the
//! penetration audit.

use glam::Vec3;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyUntypedArray, PyUntypedArrayMethods};
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

use pyo3::prelude::*;
use pyo3::types::{PyDict, PySequence};
use tegument_core::collide::{audit as core_audit, self_intersections as core_self_intersections, AuditParams, Collider as CoreCollider, ColliderSettings};
use tegument_core::mesh::MeshInput;

use crate::convert::{indices_to_py, int_array_arg, positions_arg, positions_to_py, rows_to_py, run_detached, TegumentError};

/// `(T, 3)` triangle indices (int32; other integer types converted).
fn triangles_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<[u32; 3]>> {
    // Messages say T (triangles), not the generic N.
    let (_, flat) = crate::convert::int_grid_arg(name, obj, &[None, Some(3)])
        .map_err(|e| TegumentError::new_err(e.to_string().replacen("TegumentError: ", "", 1).replacen("(N, 3)", "(T, 3)", 1)))?;
    crate::convert::py_result(tegument_core::collide::collider::triangles_from_flat(&flat))
}

/// The core's defaults where an argument is left out; a given `friction`
/// without `kinetic_friction` is both coefficients, as it always was.
fn settings(thickness: f32, friction: Option<f32>, kinetic_friction: Option<f32>) -> ColliderSettings {
    let default = ColliderSettings::default();
    let static_friction = friction.unwrap_or(default.static_friction);
    let kinetic_friction = match (friction, kinetic_friction) {
        (_, Some(kinetic)) => kinetic,
        (Some(given), None) => given,
        (None, None) => default.kinetic_friction,
    };
    ColliderSettings { thickness, static_friction, kinetic_friction }
}

/// A kinematic triangle-mesh collider that keeps last frame's positions.
///
/// ``positions`` is float32 ``(N, 3)`` in world space, ``triangles`` int32
/// ``(T, 3)``. ``thickness`` is the distance kept between skin and surface;
/// ``friction`` the static friction coefficient (and the kinetic one unless
/// ``kinetic_friction`` is given). Left out, each takes its default from
/// ``tegument.DEFAULTS`` (the add-on's defaults too). Call :meth:`update` once per frame with the
/// new world positions: the collider then moves from the previous positions
/// to these over the frame, which is what continuous collision detection sees.
#[pyclass(module = "tegument", name = "Collider", frozen)]
pub struct Collider {
    // A lock rather than `&mut self`: `update` runs without the GIL, and a
    // step or audit using the collider from another Python thread waits for
    // it instead of getting pyo3's "already borrowed" error.
    inner: RwLock<CoreCollider>,
}

impl Collider {
    pub fn read(&self) -> RwLockReadGuard<'_, CoreCollider> {
        self.inner.read().unwrap_or_else(|e| e.into_inner())
    }

    pub fn write(&self) -> RwLockWriteGuard<'_, CoreCollider> {
        self.inner.write().unwrap_or_else(|e| e.into_inner())
    }
}

#[pymethods]
impl Collider {
    #[new]
    #[pyo3(signature = (positions, triangles, thickness=ColliderSettings::default().thickness, friction=None, kinetic_friction=None))]
    fn new(
        py: Python<'_>,
        positions: &Bound<'_, PyAny>,
        triangles: &Bound<'_, PyAny>,
        thickness: f32,
        friction: Option<f32>,
        kinetic_friction: Option<f32>,
    ) -> PyResult<Self> {
        let positions = positions_arg("positions", positions, None)?;
        let triangles = triangles_arg("triangles", triangles)?;
        let settings = settings(thickness, friction, kinetic_friction);
        let inner = run_detached(py, || CoreCollider::new(&positions, &triangles, settings))?;
        Ok(Collider { inner: RwLock::new(inner) })
    }

    /// Next frame: the current positions become the previous ones and
    /// ``positions`` (float32 ``(N, 3)``, same N) the current ones. The BVH is
    /// refitted, and rebuilt when refitting has degraded it. Returns a
    /// :class:`tegument.results.ColliderUpdate` (``cost_ratio``, ``rebuilt``).
    fn update<'py>(&self, py: Python<'py>, positions: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let count = self.read().vertex_count();
        let given = positions.cast::<PyUntypedArray>().ok().filter(|a| a.ndim() == 2).map(|a| a.shape()[0]);
        if let Some(given) = given {
            if given != count {
                return Err(TegumentError::new_err(format!("collider had {count} vertices, update gave {given}")));
            }
        }
        let positions: Vec<Vec3> = positions_arg("positions", positions, Some(count))?;
        let report = run_detached(py, move || self.write().update(&positions))?;
        let dict = PyDict::new(py);
        dict.set_item("cost_ratio", report.cost_ratio)?;
        dict.set_item("rebuilt", report.rebuilt)?;
        crate::convert::report(py, "ColliderUpdate", &dict)
    }

    /// Puts the collider at ``positions`` (float32 ``(N, 3)``) without motion
    /// (previous = current = ``positions``). A compliant collider keeps its
    /// goals: this is how a resumed bake puts it back where the last cached
    /// frame solved it.
    fn place(&self, py: Python<'_>, positions: &Bound<'_, PyAny>) -> PyResult<()> {
        let count = self.read().vertex_count();
        let positions: Vec<Vec3> = positions_arg("positions", positions, Some(count))?;
        run_detached(py, move || self.write().set_positions(&positions, &positions).map(|_| ()))
    }

    /// Forgets the motion (previous = current), e.g. after a jump in time.
    fn hold(&self, py: Python<'_>) -> PyResult<()> {
        run_detached(py, move || self.write().hold().map(|_| ()))
    }

    /// Makes vertices compliant (seed 002 §1): ``stiffness`` is ``None`` (all
    /// kinematic), a float for every vertex, or a float32 ``(N,)`` array, each
    /// ≥ 0 (0 = kinematic). A compliant vertex is pulled to its animated
    /// position (what :meth:`update` gives) by a spring of that stiffness
    /// density, relative to the skin's stiffness of 1000 (so 1000 weighs as
    /// much as the skin's own shape); :meth:`PyramidDeformer.step` then solves
    /// it with the skin, and it recedes where the two meet.
    #[pyo3(signature = (stiffness))]
    fn set_compliance(&self, py: Python<'_>, stiffness: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let n = self.read().vertex_count();
        let values: Option<Vec<f32>> = match stiffness {
            None => None,
            Some(obj) if obj.cast::<PyUntypedArray>().is_ok() => Some(crate::convert::float_array_arg("stiffness", obj, Some(n))?),
            Some(obj) => match obj.extract::<f64>() {
                Ok(k) if !obj.is_instance_of::<pyo3::types::PyBool>() => Some(vec![k as f32; n]),
                _ => {
                    let kind = obj.get_type().name().map(|s| s.to_string()).unwrap_or_default();
                    return Err(TegumentError::new_err(format!("stiffness: expected None, a float or a float32 ({n},) array; got a {kind}")));
                }
            },
        };
        run_detached(py, move || self.write().set_compliance(values.as_deref()))
    }

    /// Whether any vertex is compliant.
    #[getter]
    fn is_compliant(&self) -> bool {
        self.read().is_compliant()
    }

    /// The animated positions this frame (what :meth:`update` gave), float32
    /// ``(N, 3)``: for a compliant collider :attr:`positions` are where the
    /// last step solved it, these its goals.
    #[getter]
    fn goal_positions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        let inner = self.read();
        match inner.compliance() {
            Some(c) => positions_to_py(py, &c.goals),
            None => positions_to_py(py, inner.current()),
        }
    }

    /// Number of vertices.
    #[getter]
    fn vertex_count(&self) -> usize {
        self.read().vertex_count()
    }

    /// Number of triangles.
    #[getter]
    fn triangle_count(&self) -> usize {
        self.read().triangles().len()
    }

    /// Distance kept between the skin and the surface.
    #[getter]
    fn thickness(&self) -> f32 {
        self.read().settings().thickness
    }

    /// Static friction coefficient.
    #[getter]
    fn friction(&self) -> f32 {
        self.read().settings().static_friction
    }

    /// Kinetic friction coefficient.
    #[getter]
    fn kinetic_friction(&self) -> f32 {
        self.read().settings().kinetic_friction
    }

    /// Whether every edge has exactly two triangles (the audit's inside test
    /// applies only to closed colliders).
    #[getter]
    fn is_closed(&self) -> bool {
        self.read().is_closed()
    }

    /// This frame's positions, float32 ``(N, 3)``.
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        positions_to_py(py, self.read().current())
    }

    /// Last frame's positions, float32 ``(N, 3)``.
    #[getter]
    fn previous_positions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        positions_to_py(py, self.read().previous())
    }

    /// Triangles, int32 ``(T, 3)``.
    #[getter]
    fn triangles<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i32>> {
        rows_to_py(py, self.read().triangles())
    }

    /// Unique edges, int32 ``(E, 2)``; the audit's ``collider_edges_crossing_indices``
    /// refer to these rows. (A method in 0.1.0: ``edges()`` still works, deprecated.)
    #[getter]
    fn edges<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        crate::convert::property_array(py, rows_to_py(py, self.read().edges()).into_any(), "Collider.edges")
    }

    /// How many times the BVH was rebuilt because refitting had degraded it.
    #[getter]
    fn bvh_rebuilds(&self) -> usize {
        self.read().tree().rebuild_count()
    }

    fn __repr__(&self) -> String {
        let inner = self.read();
        let s = inner.settings();
        format!(
            "tegument.Collider({} vertices, {} triangles, thickness={}, friction={}, kinetic_friction={})",
            inner.vertex_count(),
            inner.triangles().len(),
            s.thickness,
            s.static_friction,
            s.kinetic_friction
        )
    }
}

/// Penetration audit of a mesh against colliders at their current positions.
///
/// ``positions`` float32 ``(N, 3)``, ``corner_verts`` and ``polygon_sizes`` int32
/// in Blender's layout, ``colliders`` a sequence of :class:`Collider`. Counts
/// vertices inside a closed collider deeper than ``depth_tolerance``, mesh edges
/// (with the diagonals of its fan-triangulated polygons) crossing a collider
/// triangle, and collider edges crossing a mesh polygon.
/// Returns a :class:`tegument.results.AuditReport` with the counts ``vertices_inside``, ``edges_crossing``,
/// ``collider_edges_crossing``, the index arrays ``vertices_inside_indices``
/// ``(K,)``, ``edges_crossing_indices`` ``(K, 2)`` (vertex pairs),
/// ``collider_edges_crossing_indices`` ``(K, 2)`` (collider, edge row of
/// :meth:`Collider.edges`), and ``open_colliders`` (colliders skipped by the
/// inside test because they are not closed). With ``self_intersections`` it
/// also counts the mesh's own intersections, with its own geometry (nothing of
/// the solver's): pairs of polygons sharing no vertex that intersect under
/// some split of their quads (a side or diagonal of one, a quad's two, an
/// ngon's fan diagonals, properly crosses a triangle of the other, a quad's
/// four of both splits, an ngon's fan), as ``self_intersections``
/// and ``self_intersection_indices`` ``(K, 2)`` (polygon pairs, ascending);
/// both are 0 and empty without it.
#[pyfunction]
#[pyo3(signature = (positions, corner_verts, polygon_sizes, colliders, depth_tolerance=AuditParams::default().depth_tolerance, *, self_intersections=false))]
pub fn audit<'py>(
    py: Python<'py>,
    positions: &Bound<'py, PyAny>,
    corner_verts: &Bound<'py, PyAny>,
    polygon_sizes: &Bound<'py, PyAny>,
    colliders: &Bound<'py, PyAny>,
    depth_tolerance: f32,
    self_intersections: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let positions = positions_arg("positions", positions, None)?;
    let corner_verts = int_array_arg("corner_verts", corner_verts, None)?;
    let polygon_sizes = int_array_arg("polygon_sizes", polygon_sizes, None)?;
    let refs = collider_refs(colliders)?;
    let holders: Vec<&Collider> = refs.iter().map(|r| &**r).collect();
    let params = AuditParams { depth_tolerance };
    let (report, crossing) = run_detached(py, || {
        let guards: Vec<_> = holders.iter().map(|c| c.read()).collect();
        let cols: Vec<&CoreCollider> = guards.iter().map(|g| &**g).collect();
        let mesh = MeshInput { positions: &positions, corner_verts: &corner_verts, polygon_sizes: &polygon_sizes };
        let report = core_audit(mesh, &cols, &params)?;
        let crossing = if self_intersections { core_self_intersections(mesh)? } else { Vec::new() };
        Ok((report, crossing))
    })?;
    let dict = PyDict::new(py);
    dict.set_item("vertices_inside", report.vertices_inside.len())?;
    dict.set_item("edges_crossing", report.edges_crossing.len())?;
    dict.set_item("collider_edges_crossing", report.collider_edges_crossing.len())?;
    dict.set_item("vertices_inside_indices", indices_to_py(py, &report.vertices_inside))?;
    dict.set_item("edges_crossing_indices", rows_to_py(py, &report.edges_crossing))?;
    let pairs: Vec<i32> = report.collider_edges_crossing.iter().flat_map(|&(c, e)| [c as i32, e as i32]).collect();
    let pairs = Array2::from_shape_vec((report.collider_edges_crossing.len(), 2), pairs)
        .map_err(|e| TegumentError::new_err(format!("internal error: {e}")))?;
    dict.set_item("collider_edges_crossing_indices", pairs.into_pyarray(py))?;
    dict.set_item("open_colliders", report.open_colliders.iter().map(|&c| c as usize).collect::<Vec<_>>())?;
    dict.set_item("self_intersections", crossing.len())?;
    dict.set_item("self_intersection_indices", rows_to_py(py, &crossing))?;
    crate::convert::report(py, "AuditReport", &dict)
}

/// Borrows every element of a sequence of `Collider`, naming the first that is not one.
pub fn collider_refs<'py>(colliders: &Bound<'py, PyAny>) -> PyResult<Vec<PyRef<'py, Collider>>> {
    let seq = colliders.cast::<PySequence>().map_err(|_| {
        TegumentError::new_err(format!(
            "colliders: expected a sequence of tegument.Collider, got {}",
            colliders.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into())
        ))
    })?;
    let mut out = Vec::new();
    for i in 0..seq.len()? {
        let item = seq.get_item(i)?;
        let collider = item.extract::<PyRef<'py, Collider>>().map_err(|_| {
            TegumentError::new_err(format!(
                "colliders[{i}]: expected a tegument.Collider, got {}",
                item.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into())
            ))
        })?;
        out.push(collider);
    }
    Ok(out)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Collider>()?;
    m.add_function(wrap_pyfunction!(audit, m)?)
}
