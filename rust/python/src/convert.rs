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
    Element, IntoPyArray, PyArray1, PyArray2, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn,
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

/// The element types arguments are read as, and which numpy arrays convert
/// to them: any float dtype to a float, any integer dtype to `i32` (range
/// checked). The wanted dtype in C order is read without conversion; anything
/// else costs one converting pass, never a second copy.
trait Wanted: Element + Copy {
    /// The dtype named in messages.
    const NAME: &'static str;
    /// What else is converted, for messages.
    const ALSO: &'static str;
    /// Reads `array` (already known not to be of type `Self`) into `out`,
    /// C order; `None` when its dtype is not one this type converts from.
    fn convert(name: &str, array: &Bound<'_, PyUntypedArray>, shape: &[usize], out: &mut Vec<Self>) -> Option<PyResult<()>>;
}

/// Copies an array of element `S` in C order (any memory layout) through `f`.
fn copy_as<S: Element + Copy, T>(
    name: &str,
    array: &Bound<'_, PyUntypedArray>,
    out: &mut Vec<T>,
    mut f: impl FnMut(usize, S) -> PyResult<T>,
) -> Option<PyResult<()>> {
    let typed = array.cast::<PyArrayDyn<S>>().ok()?;
    Some((|| {
        let readonly = read(name, typed)?;
        out.reserve(typed.len());
        for (k, &v) in readonly.as_array().iter().enumerate() {
            out.push(f(k, v)?);
        }
        Ok(())
    })())
}

/// Converts any float dtype: float64 and float32 (any layout) directly,
/// others (float16, longdouble) through numpy's own cast.
fn convert_float<T: Element + Copy>(
    name: &str,
    array: &Bound<'_, PyUntypedArray>,
    out: &mut Vec<T>,
    from32: fn(f32) -> T,
    from64: fn(f64) -> T,
    numpy_name: &str,
) -> Option<PyResult<()>> {
    if array.dtype().kind() != b'f' {
        return None;
    }
    if let Some(done) = copy_as::<f32, T>(name, array, out, |_, v| Ok(from32(v))) {
        return Some(done);
    }
    if let Some(done) = copy_as::<f64, T>(name, array, out, |_, v| Ok(from64(v))) {
        return Some(done);
    }
    Some((|| {
        let cast = array.call_method1("astype", (numpy_name,))?;
        let cast = cast.cast::<PyUntypedArray>().map_err(PyErr::from)?;
        copy_as::<T, T>(name, cast, out, |_, v| Ok(v)).unwrap_or_else(|| Err(TegumentError::new_err(format!("{name}: numpy did not convert it to {numpy_name}"))))
    })())
}

impl Wanted for f32 {
    const NAME: &'static str = "float32";
    const ALSO: &'static str = "other float types are converted";
    fn convert(name: &str, array: &Bound<'_, PyUntypedArray>, _shape: &[usize], out: &mut Vec<Self>) -> Option<PyResult<()>> {
        convert_float(name, array, out, |v| v, |v| v as f32, "float32")
    }
}

impl Wanted for f64 {
    const NAME: &'static str = "float64";
    const ALSO: &'static str = "other float types are converted";
    fn convert(name: &str, array: &Bound<'_, PyUntypedArray>, _shape: &[usize], out: &mut Vec<Self>) -> Option<PyResult<()>> {
        convert_float(name, array, out, |v| v as f64, |v| v, "float64")
    }
}

impl Wanted for i32 {
    const NAME: &'static str = "int32";
    const ALSO: &'static str = "other integer types are converted";
    fn convert(name: &str, array: &Bound<'_, PyUntypedArray>, shape: &[usize], out: &mut Vec<Self>) -> Option<PyResult<()>> {
        // Indices of another integer type: each must be a valid index, so
        // that the core sees the same numbers the caller wrote.
        let check = |k: usize, wide: i128| -> PyResult<i32> {
            if (0..=i32::MAX as i128).contains(&wide) {
                Ok(wide as i32)
            } else {
                Err(TegumentError::new_err(format!(
                    "{name}: element {} is {wide}; indices must be between 0 and {} (int32)",
                    element_text(k, shape),
                    i32::MAX
                )))
            }
        };
        if let Some(done) = copy_as::<i32, i32>(name, array, out, |_, v| Ok(v)) {
            return Some(done); // int32, not C-contiguous: as is
        }
        macro_rules! each {
            ($($t:ty),*) => {$(
                if let Some(done) = copy_as::<$t, i32>(name, array, out, |k, v| check(k, i128::from(v))) {
                    return Some(done);
                }
            )*};
        }
        each!(i64, i16, i8, u64, u32, u16, u8);
        None
    }
}

/// Element `k` of a C-order array of `shape`, as numpy would index it.
fn element_text(k: usize, shape: &[usize]) -> String {
    if shape.len() <= 1 {
        return k.to_string();
    }
    let mut index = vec![0; shape.len()];
    let mut rest = k;
    for (slot, &n) in index.iter_mut().zip(shape).rev() {
        *slot = rest % n.max(1);
        rest /= n.max(1);
    }
    format!("({})", index.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(", "))
}

/// Reads `obj`, a numpy array whose shape matches `shape` (`None` = any
/// length), as a flat C-order `Vec<T>` plus its shape. An array of `T` in C
/// order is copied as is; another dtype of the same family (any float for a
/// float, any integer for `i32`) or another layout is converted on the way
/// (see [`Wanted`]); bool, complex, object arrays and non-arrays are refused.
fn array_values<T: Wanted>(name: &str, obj: &Bound<'_, PyAny>, shape: &[Option<usize>]) -> PyResult<(Vec<usize>, Vec<T>)> {
    let fail = || {
        TegumentError::new_err(format!(
            "{name}: expected {} {} ({}); got {}",
            T::NAME,
            shape_text(shape),
            T::ALSO,
            describe(obj)
        ))
    };
    let array = obj.cast::<PyUntypedArray>().map_err(|_| fail())?;
    let actual = array.shape().to_vec();
    let shape_ok = actual.len() == shape.len() && actual.iter().zip(shape).all(|(&a, want)| want.is_none_or(|w| w == a));
    if !shape_ok {
        return Err(fail());
    }
    if let Ok(typed) = array.cast::<PyArrayDyn<T>>() {
        if typed.is_c_contiguous() {
            let readonly = read(name, typed)?;
            let flat = readonly.as_slice().map_err(|e| TegumentError::new_err(format!("{name}: {e}")))?;
            return Ok((actual, flat.to_vec()));
        }
    }
    let mut out = Vec::new();
    match T::convert(name, array, &actual, &mut out) {
        Some(done) => done.map(|()| (actual, out)),
        None => Err(fail()),
    }
}

/// `(N, 3)` positions (float32, other floats converted), checked finite.
/// `expected_count` fixes N.
pub fn positions_arg(name: &str, obj: &Bound<'_, PyAny>, expected_count: Option<usize>) -> PyResult<Vec<Vec3>> {
    let positions = points_arg(name, obj, expected_count)?;
    py_result(tegument_core::mesh::validate_positions(name, &positions))?;
    Ok(positions)
}

/// `(N, 3)` points, values not checked (for pure transforms, which
/// carry a non-finite value through for the caller to report in its terms).
pub fn points_arg(name: &str, obj: &Bound<'_, PyAny>, expected_count: Option<usize>) -> PyResult<Vec<Vec3>> {
    let mut points = Vec::new();
    points_into(name, obj, expected_count, &mut points)?;
    Ok(points)
}

/// [`points_arg`] into `points`, whose allocation is reused. A bake reads
/// millions of positions every frame, and a fresh buffer of that size costs
/// more in page faults than copying into it.
pub fn points_into(name: &str, obj: &Bound<'_, PyAny>, expected_count: Option<usize>, points: &mut Vec<Vec3>) -> PyResult<()> {
    points.clear();
    if let Ok(typed) = obj.cast::<PyArray2<f32>>() {
        let shape = typed.shape();
        let shape_ok = shape[1] == 3 && expected_count.is_none_or(|n| n == shape[0]);
        if shape_ok && typed.is_c_contiguous() {
            let readonly = typed
                .try_readonly()
                .map_err(|e| TegumentError::new_err(format!("{name}: the array is being written elsewhere ({e})")))?;
            let flat = readonly.as_slice().map_err(|e| TegumentError::new_err(format!("{name}: {e}")))?;
            points.extend_from_slice(bytemuck::cast_slice(flat));
            return Ok(());
        }
    }
    // Any other dtype or layout: one converting pass (the messages are array_values').
    let (_, flat) = array_values::<f32>(name, obj, &[expected_count, Some(3)])?;
    points.extend_from_slice(bytemuck::cast_slice(&flat));
    Ok(())
}

/// `out`, an optional float32 `(N, 3)` array a result is written into
/// instead of a new one (a bake reuses one per frame): C-contiguous and
/// writable, or refused naming what it is.
pub fn out_arg<'py>(out: &Bound<'py, PyAny>, count: usize) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let fail = || {
        TegumentError::new_err(format!(
            "out: expected a writable C-contiguous float32 array of shape ({count}, 3); got {}",
            describe(out)
        ))
    };
    let array = out.cast::<PyArray2<f32>>().map_err(|_| fail())?;
    if array.shape() != [count, 3] || !array.is_c_contiguous() || array.try_readwrite().is_err() {
        return Err(fail());
    }
    Ok(array.clone())
}

/// `out` checked by [`out_arg`], or a new float32 `(count, 3)` array.
pub fn out_or_new<'py>(py: Python<'py>, out: Option<&Bound<'py, PyAny>>, count: usize) -> PyResult<Bound<'py, PyArray2<f32>>> {
    match out {
        Some(out) => out_arg(out, count),
        None => Ok(PyArray2::<f32>::zeros(py, [count, 3], false)),
    }
}

/// A `(4, 4)` matrix in row-major order (what `numpy.array` makes of a
/// Blender `Matrix`; float64, other floats converted), checked finite;
/// returned as glam's column-major matrix.
pub fn matrix_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<glam::DMat4> {
    let (_, flat) = array_values::<f64>(name, obj, &[Some(4), Some(4)])?;
    if let Some(k) = flat.iter().position(|v| !v.is_finite()) {
        return Err(TegumentError::new_err(format!("{name}: element ({}, {}) is {}, not finite", k / 4, k % 4, flat[k])));
    }
    let rows: &[f64; 16] = flat.as_slice().try_into().expect("shape checked: 16 elements");
    Ok(glam::DMat4::from_cols_array(rows).transpose())
}

/// A 1-D index array (int32; other integer types converted and range
/// checked), any length unless `expected_len` is given.
pub fn int_array_arg(name: &str, obj: &Bound<'_, PyAny>, expected_len: Option<usize>) -> PyResult<Vec<i32>> {
    Ok(array_values::<i32>(name, obj, &[expected_len])?.1)
}

/// An index array of the given shape (int32; other integer types converted
/// and range checked), flattened in C order.
pub fn int_grid_arg(name: &str, obj: &Bound<'_, PyAny>, shape: &[Option<usize>]) -> PyResult<(Vec<usize>, Vec<i32>)> {
    array_values::<i32>(name, obj, shape)
}

/// A 1-D float32 array (other floats converted), any length unless
/// `expected_len` is given.
pub fn float_array_arg(name: &str, obj: &Bound<'_, PyAny>, expected_len: Option<usize>) -> PyResult<Vec<f32>> {
    Ok(array_values::<f32>(name, obj, &[expected_len])?.1)
}

/// A float32 array (other floats converted) of the given shape, flattened in C order.
pub fn float_grid_arg(name: &str, obj: &Bound<'_, PyAny>, shape: &[Option<usize>]) -> PyResult<(Vec<usize>, Vec<f32>)> {
    array_values::<f32>(name, obj, shape)
}

/// One of the report classes of `tegument.results`, built from its fields.
/// The classes are Python dataclasses (frozen, `to_dict()`, the old dict
/// spellings deprecated) so that scripts can read and type them like any
/// Python object; the bindings only fill them in.
pub fn report<'py>(py: Python<'py>, class: &str, fields: &Bound<'py, pyo3::types::PyDict>) -> PyResult<Bound<'py, PyAny>> {
    py.import("tegument.results")?.getattr(class)?.call((), Some(fields))
}

/// An array returned by a property that was a method in 0.1.0: calling it
/// still works, with a `DeprecationWarning` (see `tegument.results.PropertyArray`).
pub fn property_array<'py>(py: Python<'py>, array: Bound<'py, PyAny>, spelling: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("tegument.results")?.getattr("_property_array")?.call1((array, spelling))
}

/// Warns with a `DeprecationWarning` from the caller's line.
pub fn deprecated(py: Python<'_>, message: &str) -> PyResult<()> {
    let category = py.get_type::<pyo3::exceptions::PyDeprecationWarning>();
    PyErr::warn(py, &category, &std::ffi::CString::new(message).unwrap_or_default(), 1)
}

/// `(N, 3)` float32 array from vectors.
pub fn positions_to_py<'py>(py: Python<'py>, positions: &[Vec3]) -> Bound<'py, PyArray2<f32>> {
    let array = PyArray2::<f32>::zeros(py, [positions.len(), 3], false);
    copy_positions_to(&array, positions);
    array
}

/// Copies `positions` into `array`, a C-contiguous float32 `(N, 3)` array
/// this module made or [`out_arg`] checked.
pub fn copy_positions_to(array: &Bound<'_, PyArray2<f32>>, positions: &[Vec3]) {
    let mut writable = array.readwrite();
    let flat = writable.as_slice_mut().expect("C-contiguous, checked by the caller");
    flat.copy_from_slice(bytemuck::cast_slice(positions));
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
