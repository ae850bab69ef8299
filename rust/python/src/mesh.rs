//! `tegument.Mesh`: validated topology of a Blender-layout mesh.

use pyo3::prelude::*;
use pyo3::types::PyDict;
use tegument_core::mesh::{MeshInput, Topology};

use crate::convert::{indices_to_py, int_array_arg, matrix_arg, out_or_new, points_arg, positions_arg, property_array, rows_to_py, run_detached, TegumentError};
use numpy::{PyArray1, PyArray2, PyArrayMethods};

/// The topology of a polygon mesh given in Blender's layout.
///
/// ``positions`` is float32 ``(N, 3)``, ``corner_verts`` int32 ``(L,)`` (the vertex
/// of every face corner, polygon after polygon, as ``mesh.corner_verts``) and
/// ``polygon_sizes`` int32 ``(P,)`` (``polygon.loop_total``). Raises
/// ``TegumentError`` naming the first problem found in the arrays.
#[pyclass(module = "tegument", name = "Mesh", frozen)]
pub struct Mesh {
    topology: Topology,
}

#[pymethods]
impl Mesh {
    #[new]
    fn new(
        py: Python<'_>,
        positions: &Bound<'_, PyAny>,
        corner_verts: &Bound<'_, PyAny>,
        polygon_sizes: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let positions = positions_arg("positions", positions, None)?;
        let corner_verts = int_array_arg("corner_verts", corner_verts, None)?;
        let polygon_sizes = int_array_arg("polygon_sizes", polygon_sizes, None)?;
        let topology = run_detached(py, || {
            Topology::build(MeshInput { positions: &positions, corner_verts: &corner_verts, polygon_sizes: &polygon_sizes })
        })?;
        Ok(Mesh { topology })
    }

    /// Number of vertices.
    #[getter]
    fn vertex_count(&self) -> usize {
        self.topology.vertex_count()
    }

    /// Number of polygons.
    #[getter]
    fn polygon_count(&self) -> usize {
        self.topology.polygon_count()
    }

    /// Unique edges as int32 ``(E, 2)``, each ``[low, high]``, sorted.
    /// (A method in 0.1.0: ``edges()`` still works, deprecated.)
    #[getter]
    fn edges<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        property_array(py, rows_to_py(py, self.topology.edges()).into_any(), "Mesh.edges")
    }

    /// Indices of the vertices on a boundary edge, int32 ``(B,)``.
    /// (A method in 0.1.0: ``boundary_vertices()`` still works, deprecated.)
    #[getter]
    fn boundary_vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        property_array(py, indices_to_py(py, &self.topology.report().boundary_vertices).into_any(), "Mesh.boundary_vertices")
    }

    /// The neighbours of vertex ``i``, counter-clockwise around the surface
    /// normal; for a boundary vertex, from one boundary neighbour to the other.
    fn one_ring<'py>(&self, py: Python<'py>, i: i64) -> PyResult<Bound<'py, PyArray1<i32>>> {
        let count = self.topology.vertex_count();
        if i < 0 || i as u64 >= count as u64 {
            return Err(TegumentError::new_err(format!("vertex {i} is out of range: the mesh has {count} vertices")));
        }
        Ok(indices_to_py(py, self.topology.one_ring(i as usize)))
    }

    /// Vertices an artist should look at: ends of non-manifold or flipped
    /// edges, bow-ties, corners of degenerate polygons, isolated vertices.
    fn problem_vertices<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i32>> {
        indices_to_py(py, &self.topology.problem_vertices())
    }

    /// Counts of everything unusual, plus ``is_closed_manifold`` and
    /// ``is_clean``: a :class:`tegument.results.MeshReport`. (A method in
    /// 0.1.0: ``report()`` still works, deprecated.)
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let report = self.topology.report();
        let dict = PyDict::new(py);
        dict.set_item("vertex_count", report.vertex_count)?;
        dict.set_item("edge_count", report.edge_count)?;
        dict.set_item("polygon_count", report.polygon_count)?;
        dict.set_item("boundary_edges", report.boundary_edges.len())?;
        dict.set_item("boundary_vertices", report.boundary_vertices.len())?;
        dict.set_item("non_manifold_edges", report.non_manifold_edges.len())?;
        dict.set_item("flipped_edges", report.flipped_edges.len())?;
        dict.set_item("non_manifold_vertices", report.non_manifold_vertices.len())?;
        dict.set_item("degenerate_polygons", report.degenerate_polygons.len())?;
        dict.set_item("isolated_vertices", report.isolated_vertices.len())?;
        dict.set_item("is_closed_manifold", report.is_closed_manifold())?;
        dict.set_item("is_clean", report.is_clean())?;
        crate::convert::report(py, "MeshReport", &dict)
    }

    fn __repr__(&self) -> String {
        let report = self.topology.report();
        format!(
            "tegument.Mesh({} vertices, {} edges, {} polygons)",
            report.vertex_count, report.edge_count, report.polygon_count
        )
    }
}

/// Applies an object matrix to points: float32 ``(N, 3)`` in, a new float32
/// ``(N, 3)`` array out (or ``out``, as in :meth:`PyramidDeformer.solve`),
/// ``matrix @ (x, y, z, 1)`` for every point.
///
/// ``matrix`` is float64 ``(4, 4)`` in row-major order, as
/// ``numpy.array(obj.matrix_world)`` gives it; its affine part (the first
/// three rows) is applied in double precision and rounded once. Points are
/// not checked: a non-finite point stays non-finite. Runs on all cores,
/// without the GIL; several times faster than ``points @ matrix[:3, :3].T``
/// in numpy for a 100k-vertex mesh.
#[pyfunction]
#[pyo3(signature = (points, matrix, *, out = None))]
fn transform_points<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    matrix: &Bound<'py, PyAny>,
    out: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let points = points_arg("points", points, None)?;
    let matrix = matrix_arg("matrix", matrix)?;
    let output = out_or_new(py, out, points.len())?;
    {
        let mut writable = output.readwrite();
        let out: &mut [glam::Vec3] = bytemuck::cast_slice_mut(writable.as_slice_mut().expect("C-contiguous: made here or checked"));
        run_detached(py, move || {
            tegument_core::mesh::transform_points(&matrix, &points, out);
            Ok(())
        })?;
    }
    Ok(output)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Mesh>()?;
    m.add_function(wrap_pyfunction!(transform_points, m)?)
}
