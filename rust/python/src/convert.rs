//! Checked conversions between numpy arrays and core data, and the error
//! type Python sees.
//!
//! Every array argument goes through one of the `*_arg` functions so that a
//! wrong dtype, shape or memory layout gets the same kind of message
//! everywhere: what was expected, what was given, and which argument.

use std::panic::{catch_unwind, AssertUnwindSafe};

use glam::Vec3;
use numpy::ndarray::Array2;
use numpy::{
    Element, IntoPyArray, PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn,
    PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

pyo3::create_exception!(
    tegument,
    TegumentError,
    PyValueError,
    "Raised for any input Tegument refuses; the message names what is wrong and where."
);

/// Turns a core error into the Python exception.
pub fn to_py_err(err: tegument_core::Error) -> PyErr {
    TegumentError::new_err(err.to_string())
}

/// Shorthand: a core result as a Python result.
pub fn py_result<T>(result: tegument_core::Result<T>) -> PyResult<T> {
    result.map_err(to_py_err)
}

/// Runs core work without the GIL, turning a panic (a bug, never expected on
/// any input) into a `TegumentError` instead of letting it reach Blender.
pub fn run_detached<T: Send>(
    py: Python<'_>,
    work: impl FnOnce() -> tegument_core::Result<T> + Send,
) -> PyResult<T> {
    let outcome = py.detach(|| catch_unwind(AssertUnwindSafe(work)));
    match outcome {
        Ok(result) => py_result(result),
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(TegumentError::new_err(format!(
                "internal error in Tegument (please report it): {what}"
            )))
        }
    }
}

fn describe(obj: &Bound<'_, PyAny>) -> String {
    match obj.cast::<PyUntypedArray>() {
        Ok(array) => {
            let layout = if array.is_c_contiguous() { "" } else { ", not C-contiguous" };
            let shape: Vec<Option<usize>> = array.shape().iter().map(|&n| Some(n)).collect();
            let dtype = array.dtype().str().map(|s| s.to_string()).unwrap_or_default();
            format!("{dtype} {}{layout}", shape_text(&shape))
        }
        Err(_) => format!("a {}", obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into())),
    }
}

fn shape_text(shape: &[Option<usize>]) -> String {
    let parts: Vec<String> = shape.iter().map(|d| d.map(|n| n.to_string()).unwrap_or_else(|| "N".into())).collect();
    if parts.len() == 1 {
        format!("({},)", parts[0])
    } else {
        format!("({})", parts.join(", "))
    }
}

/// Checks that `obj` is a C-contiguous numpy array of element `T` whose shape
/// matches `shape` (`None` = any length), and returns it read-only.
fn checked_array<'py, T: Element>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    dtype_name: &str,
    shape: &[Option<usize>],
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    let fail = || {
        TegumentError::new_err(format!(
            "{name}: expected {dtype_name} {}, C-contiguous; got {}",
            shape_text(shape),
            describe(obj)
        ))
    };
    let array = obj.cast::<PyArrayDyn<T>>().map_err(|_| fail())?;
    let actual = array.shape();
    let shape_ok = actual.len() == shape.len()
        && actual.iter().zip(shape).all(|(&a, want)| want.is_none_or(|w| w == a));
    if !shape_ok || !array.is_c_contiguous() {
        return Err(fail());
    }
    Ok(array.clone())
}

/// `(N, 3)` float32 positions, checked finite. `expected_count` fixes N.
pub fn positions_arg(name: &str, obj: &Bound<'_, PyAny>, expected_count: Option<usize>) -> PyResult<Vec<Vec3>> {
    let positions = points_arg(name, obj, expected_count)?;
    py_result(tegument_core::mesh::validate_positions(name, &positions))?;
    Ok(positions)
}

/// `(N, 3)` float32 points, values not checked (for pure transforms, which
/// carry a non-finite value through for the caller to report in its terms).
pub fn points_arg(name: &str, obj: &Bound<'_, PyAny>, expected_count: Option<usize>) -> PyResult<Vec<Vec3>> {
    let array = checked_array::<f32>(name, obj, "float32", &[expected_count, Some(3)])?;
    let readonly = read(name, &array)?;
    let flat = readonly.as_slice().map_err(|e| TegumentError::new_err(format!("{name}: {e}")))?;
    Ok(bytemuck::cast_slice::<f32, Vec3>(flat).to_vec())
}

/// A `(4, 4)` float64 matrix in row-major order (what `numpy.array` makes of a
/// Blender `Matrix`), checked finite; returned as glam's column-major matrix.
pub fn matrix_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<glam::DMat4> {
    let array = checked_array::<f64>(name, obj, "float64", &[Some(4), Some(4)])?;
    let readonly = read(name, &array)?;
    let flat = readonly.as_slice().map_err(|e| TegumentError::new_err(format!("{name}: {e}")))?;
    if let Some(k) = flat.iter().position(|v| !v.is_finite()) {
        return Err(TegumentError::new_err(format!("{name}: element ({}, {}) is {}, not finite", k / 4, k % 4, flat[k])));
    }
    let rows: &[f64; 16] = flat.try_into().expect("shape checked: 16 elements");
    Ok(glam::DMat4::from_cols_array(rows).transpose())
}

/// A 1-D int32 array (any length unless `expected_len` is given).
pub fn int_array_arg(name: &str, obj: &Bound<'_, PyAny>, expected_len: Option<usize>) -> PyResult<Vec<i32>> {
    let array = checked_array::<i32>(name, obj, "int32", &[expected_len])?;
    let readonly = read(name, &array)?;
    Ok(readonly.as_slice().map_err(|e| TegumentError::new_err(format!("{name}: {e}")))?.to_vec())
}

/// A 1-D float32 array (any length unless `expected_len` is given).
pub fn float_array_arg(name: &str, obj: &Bound<'_, PyAny>, expected_len: Option<usize>) -> PyResult<Vec<f32>> {
    let array = checked_array::<f32>(name, obj, "float32", &[expected_len])?;
    let readonly = read(name, &array)?;
    Ok(readonly.as_slice().map_err(|e| TegumentError::new_err(format!("{name}: {e}")))?.to_vec())
}

/// A float32 array of the given shape, flattened in C order.
pub fn float_grid_arg(name: &str, obj: &Bound<'_, PyAny>, shape: &[Option<usize>]) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let array = checked_array::<f32>(name, obj, "float32", shape)?;
    let readonly = read(name, &array)?;
    let data = readonly.as_slice().map_err(|e| TegumentError::new_err(format!("{name}: {e}")))?.to_vec();
    Ok((array.shape().to_vec(), data))
}

/// `(N, 3)` float32 array from vectors.
pub fn positions_to_py<'py>(py: Python<'py>, positions: &[Vec3]) -> Bound<'py, PyArray2<f32>> {
    let flat: Vec<f32> = bytemuck::cast_slice::<Vec3, f32>(positions).to_vec();
    Array2::from_shape_vec((positions.len(), 3), flat)
        .expect("length is 3 × count by construction")
        .into_pyarray(py)
}

/// `(N, K)` int32 array from fixed-size rows.
pub fn rows_to_py<'py, const K: usize>(py: Python<'py>, rows: &[[u32; K]]) -> Bound<'py, PyArray2<i32>> {
    let flat: Vec<i32> = rows.iter().flatten().map(|&v| v as i32).collect();
    Array2::from_shape_vec((rows.len(), K), flat)
        .expect("length is K × count by construction")
        .into_pyarray(py)
}

/// `(N,)` int32 array from indices.
pub fn indices_to_py<'py>(py: Python<'py>, indices: &[u32]) -> Bound<'py, PyArray1<i32>> {
    PyArray1::from_iter(py, indices.iter().map(|&v| v as i32))
}

/// A read-only view, refused (not panicking) while someone holds it writable.
fn read<'py, T: Element>(name: &str, array: &Bound<'py, PyArrayDyn<T>>) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    array
        .try_readonly()
        .map_err(|e| TegumentError::new_err(format!("{name}: the array is being written elsewhere ({e})")))
}
