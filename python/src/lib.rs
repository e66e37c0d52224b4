//! The Python module `mspace_slam`: its function `run` runs a configuration as `slam run`
//! does (the same library function, [`slam_cli::compute_run`]) and returns the results as
//! NumPy arrays and dicts instead of files.
//!
//! Built by maturin (`pip install ./python`, see python/README.md); tested by pytest
//! (python/tests).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use slam_cli::{CliError, RunResults, compute_run, map_json, with_overrides};
use slam_runtime::{Config, Observer, RuntimeError};
use slam_sensors::{SensorError, TruthKind};

/// Where a configuration comes from.
enum ConfigSource {
    /// The defaults.
    Default,
    /// A TOML file.
    File(PathBuf),
    /// TOML text, and where it came from (`"inline"`, `"dict"`).
    Text(String, &'static str),
}

impl ConfigSource {
    /// The configuration (an error names the key at fault, as `slam run` does).
    fn load(&self) -> slam_cli::Result<Config> {
        Ok(match self {
            ConfigSource::Default => Config::default(),
            ConfigSource::File(path) => Config::from_file(path)?,
            ConfigSource::Text(text, origin) => Config::from_toml(text, origin)?,
        })
    }
}

/// The Python exception class of an error of a run.
#[derive(Clone, Copy)]
enum ErrorClass {
    /// A configuration or data the run cannot use.
    Value,
    /// A file that does not exist.
    FileNotFound,
    /// Another failure to read a file.
    Os,
    /// A failure during the run (an estimator's, a bug).
    Runtime,
}

fn sensor_class(error: &SensorError) -> ErrorClass {
    match error {
        SensorError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            ErrorClass::FileNotFound
        }
        SensorError::Io { .. } => ErrorClass::Os,
        SensorError::Core(_) => ErrorClass::Runtime,
        _ => ErrorClass::Value,
    }
}

fn runtime_class(error: &RuntimeError) -> ErrorClass {
    match error {
        RuntimeError::Config { .. } | RuntimeError::Setting { .. } | RuntimeError::Data(_) => {
            ErrorClass::Value
        }
        RuntimeError::Sensor(e) => sensor_class(e),
        RuntimeError::Prior(_) => ErrorClass::Value,
        _ => ErrorClass::Runtime,
    }
}

/// An error of the command as the class and the message `slam run` prints (after `slam: `).
fn classify(error: &CliError) -> (ErrorClass, String) {
    let class = match error {
        CliError::Runtime(e) => runtime_class(e),
        CliError::Sensor(e) => sensor_class(e),
        CliError::Usage(_) | CliError::Prior(_) => ErrorClass::Value,
        _ => ErrorClass::Runtime,
    };
    (class, error.chain())
}

fn to_py_err((class, message): (ErrorClass, String)) -> PyErr {
    match class {
        ErrorClass::Value => PyValueError::new_err(message),
        ErrorClass::FileNotFound => PyFileNotFoundError::new_err(message),
        ErrorClass::Os => PyOSError::new_err(message),
        ErrorClass::Runtime => PyRuntimeError::new_err(message),
    }
}

/// A pose as a row: time, x, y, theta.
type PoseRow = [f64; 4];

/// What Python gets of a run, computed without the GIL (plain data only).
struct Results {
    metrics_json: String,
    map_json: String,
    trajectory: Vec<PoseRow>,
    covariance: Vec<[f64; 9]>,
    map_path: Option<Vec<PoseRow>>,
    reference: Vec<PoseRow>,
    warnings: Vec<String>,
}

impl Results {
    fn of(results: &RunResults) -> slam_cli::Result<Self> {
        let output = &results.output;
        let record = &output.record;
        let metrics_json = serde_json::to_string(&results.metrics).map_err(|e| {
            RuntimeError::Invariant(format!("serializing the metrics as JSON: {e}"))
        })?;
        // The poses the ATE compares against: the true ones where there are any, else the
        // reference ones (`ate_against` in the metrics says which).
        let kind = if record.truth.iter().any(|(_, _, k)| *k == TruthKind::True) {
            TruthKind::True
        } else {
            TruthKind::Reference
        };
        Ok(Results {
            metrics_json,
            map_json: map_json(output.estimator.as_ref())?,
            trajectory: record
                .estimates
                .iter()
                .map(|r| [r.time, r.pose.x, r.pose.y, r.pose.theta])
                .collect(),
            covariance: record
                .estimates
                .iter()
                .map(|r| std::array::from_fn(|k| r.covariance[(k / 3, k % 3)]))
                .collect(),
            map_path: output
                .map_path
                .as_ref()
                .map(|path| path.iter().map(|(t, p)| [*t, p.x, p.y, p.theta]).collect()),
            reference: record
                .truth
                .iter()
                .filter(|(_, _, k)| *k == kind)
                .map(|(t, p, _)| [*t, p.x, p.y, p.theta])
                .collect(),
            warnings: output.input.warnings.clone(),
        })
    }
}

/// Checks for Ctrl-C (Python's signal handlers) every tenth of a second during a run; on a
/// signal's exception, stops the run at the next event and keeps the exception.
struct SignalWatch<'a> {
    stop: &'a AtomicBool,
    checked: Instant,
    raised: Option<PyErr>,
}

impl Observer for SignalWatch<'_> {
    fn event(
        &mut self,
        _: &slam_sensors::TimedEvent,
        _: Option<&slam_core::UpdateReport>,
        _: &dyn slam_core::Estimator<slam_core::Pose2>,
    ) -> slam_runtime::Result<()> {
        if self.raised.is_none() && self.checked.elapsed() > Duration::from_millis(100) {
            self.checked = Instant::now();
            if let Err(error) = Python::attach(|py| py.check_signals()) {
                self.raised = Some(error);
                self.stop.store(true, Ordering::Relaxed);
            }
        }
        Ok(())
    }
}

/// Runs the configuration (the GIL released) and keeps what Python gets of it; a signal's
/// exception (KeyboardInterrupt) is returned as it is.
fn run_detached(
    source: ConfigSource,
    data: Option<String>,
    seed: Option<u64>,
) -> Result<Results, RunFailure> {
    let config = source.load().map_err(|e| RunFailure::Error(classify(&e)))?;
    let config = with_overrides(config, data.as_deref(), seed);
    let stop = AtomicBool::new(false);
    let mut watch = SignalWatch {
        stop: &stop,
        checked: Instant::now(),
        raised: None,
    };
    let computed = compute_run(&config, &mut watch, &stop);
    if let Some(raised) = watch.raised {
        return Err(RunFailure::Signal(raised));
    }
    computed
        .and_then(|results| Results::of(&results))
        .map_err(|e| RunFailure::Error(classify(&e)))
}

/// Why a run gave no results.
enum RunFailure {
    /// An error of the command: its class and message.
    Error((ErrorClass, String)),
    /// A signal's exception raised during the run.
    Signal(PyErr),
}

/// The configuration argument: None, a path (str or os.PathLike), TOML text, or a dict.
fn config_source(config: Option<&Bound<'_, PyAny>>) -> PyResult<ConfigSource> {
    let Some(config) = config.filter(|c| !c.is_none()) else {
        return Ok(ConfigSource::Default);
    };
    if let Ok(dict) = config.cast::<PyDict>() {
        let table = toml_table(dict, "")?;
        let text = toml::to_string(&table).map_err(|e| {
            PyValueError::new_err(format!("config dict: cannot be written as TOML: {e}"))
        })?;
        return Ok(ConfigSource::Text(text, "dict"));
    }
    if let Ok(text) = config.cast::<PyString>() {
        let text = text.to_cow()?.into_owned();
        // TOML text has a table header or a key = value; a path has neither.
        let is_toml = text.trim().is_empty()
            || text.contains('\n')
            || text.contains('=')
            || text.trim_start().starts_with('[');
        return Ok(if is_toml {
            ConfigSource::Text(text, "inline")
        } else {
            ConfigSource::File(PathBuf::from(text))
        });
    }
    if let Ok(path) = config.extract::<PathBuf>() {
        return Ok(ConfigSource::File(path));
    }
    Err(PyTypeError::new_err(format!(
        "config: expected None, a path, TOML text or a dict, got {}",
        config.get_type().name()?
    )))
}

/// A Python dict as a TOML table (keys must be strings; `key` names where it is, for errors).
fn toml_table(dict: &Bound<'_, PyDict>, key: &str) -> PyResult<toml::Table> {
    let mut table = toml::Table::new();
    for (k, v) in dict.iter() {
        let name: String = k.extract().map_err(|_| {
            PyTypeError::new_err(format!("config dict: key {k:?} in [{key}] is not a str"))
        })?;
        let path = if key.is_empty() {
            name.clone()
        } else {
            format!("{key}.{name}")
        };
        table.insert(name, toml_value(&v, &path)?);
    }
    Ok(table)
}

/// A Python value (bool, int, float, str, list or tuple, dict) as a TOML value.
fn toml_value(value: &Bound<'_, PyAny>, key: &str) -> PyResult<toml::Value> {
    if value.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        let n: i64 = value.extract().map_err(|_| {
            PyValueError::new_err(format!("config dict: {key} = {value}: out of TOML's range"))
        })?;
        return Ok(toml::Value::Integer(n));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(value.extract()?));
    }
    if let Ok(text) = value.cast::<PyString>() {
        return Ok(toml::Value::String(text.to_cow()?.into_owned()));
    }
    if let Ok(dict) = value.cast::<PyDict>() {
        return Ok(toml::Value::Table(toml_table(dict, key)?));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items = value
            .try_iter()?
            .map(|item| toml_value(&item?, key))
            .collect::<PyResult<Vec<_>>>()?;
        return Ok(toml::Value::Array(items));
    }
    if let Ok(path) = value.extract::<PathBuf>() {
        return Ok(toml::Value::String(path.display().to_string()));
    }
    Err(PyTypeError::new_err(format!(
        "config dict: {key}: a {} has no TOML form (use bool, int, float, str, list or dict)",
        value.get_type().name()?
    )))
}

/// Rows of poses as a float64 array of shape (N, 4).
fn pose_array<'py>(py: Python<'py>, rows: &[PoseRow]) -> PyResult<Bound<'py, PyAny>> {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    Ok(PyArray1::from_vec(py, flat)
        .reshape([rows.len(), 4])?
        .into_any())
}

/// Run the estimator of a configuration on simulated or real data, as `slam run` does, and
/// return the results instead of writing files.
///
/// Arguments:
///     config: None (the defaults: the EKF on the built-in simulated world), a path to a
///         TOML file (str or os.PathLike; a str with a newline, `=` or a leading `[` is
///         read as TOML text instead), TOML text, or a dict of the same tables and keys
///         (e.g. {"estimator": {"type": "fastslam", "particles": 20}}). The `[output]`
///         table is ignored: nothing is written.
///     data: a data spec, as `slam run --data`: "sim", "world:FILE", "carmen:FILE",
///         "victoria-park:DIR", "mrclam:DIR" or "mrclam:DIR:ROBOT", "rb2d:FILE". Replaces
///         the config's `[data] spec`.
///     seed: the simulation seed; replaces the config's `[data] seed`.
///
/// Returns a dict:
///     "trajectory": float64 array (N, 4), the estimated pose after each time step:
///         time (s, or sequence number where the data have no clock), x (m), y (m),
///         theta (rad), in the map frame; the poses of `trajectory.tum`.
///     "covariance": float64 array (N, 3, 3), each pose's covariance (x, y, theta).
///     "map": list of dicts, one per feature, as in `map.json` ("id", "type",
///         "mspace_dim", "confirmed", "coordinates", "covariance", ...).
///     "shared_blocks": list of dicts, the map's shared blocks (wall corners), as in
///         `map.json`.
///     "metrics": dict, the content of `metrics.json` ("ate_rmse_m", "map_error_m",
///         "nees", "steps", "status", ...).
///     "reference": float64 array (M, 4) of the data's true poses (t, x, y, theta), or of
///         its reference poses where it has no true ones; present only when the data have
///         either (`metrics["ate_against"]` says which the ATE uses).
///     "map_path": float64 array (N, 4), the path the map belongs to, present only for
///         particle filters (`map_path.tum`).
///
/// Warnings about the data (`metrics["input"]["warnings"]`) are also issued as Python
/// warnings (UserWarning). Ctrl-C stops the run and raises KeyboardInterrupt.
///
/// Raises:
///     ValueError: a configuration or data the run cannot use, with the message `slam run`
///         prints (naming the key, or the file and line).
///     FileNotFoundError, OSError: a data file that cannot be read (the message names it).
///     RuntimeError: a failure during the run.
///     TypeError: a config of another type.
#[pyfunction]
#[pyo3(signature = (config=None, data=None, seed=None))]
fn run<'py>(
    py: Python<'py>,
    config: Option<&Bound<'py, PyAny>>,
    data: Option<String>,
    seed: Option<u64>,
) -> PyResult<Bound<'py, PyDict>> {
    let source = config_source(config)?;
    let results = py
        .detach(move || run_detached(source, data, seed))
        .map_err(|failure| match failure {
            RunFailure::Error(error) => to_py_err(error),
            RunFailure::Signal(raised) => raised,
        })?;
    let json = py.import("json")?;
    let out = PyDict::new(py);
    out.set_item("trajectory", pose_array(py, &results.trajectory)?)?;
    let covariance: Vec<f64> = results.covariance.iter().flatten().copied().collect();
    out.set_item(
        "covariance",
        PyArray1::from_vec(py, covariance).reshape([results.covariance.len(), 3, 3])?,
    )?;
    let map = json.call_method1("loads", (results.map_json,))?;
    out.set_item("map", map.get_item("features")?)?;
    out.set_item("shared_blocks", map.get_item("shared_blocks")?)?;
    out.set_item(
        "metrics",
        json.call_method1("loads", (results.metrics_json,))?,
    )?;
    if !results.reference.is_empty() {
        out.set_item("reference", pose_array(py, &results.reference)?)?;
    }
    if let Some(path) = &results.map_path {
        out.set_item("map_path", pose_array(py, path)?)?;
    }
    if !results.warnings.is_empty() {
        let warn = py.import("warnings")?;
        for warning in results.warnings {
            warn.call_method1("warn", (warning,))?;
        }
    }
    Ok(out)
}

/// mspace_slam: the M-space SLAM framework (the `slam` command) from Python.
///
/// `run(config=None, data=None, seed=None)` runs an estimator on simulated or real data
/// through the same code as `slam run` and returns the estimated trajectory (NumPy), the
/// map and the metrics (dicts, as `map.json` and `metrics.json`).
///
/// Example (the EKF on the built-in world):
///
///     import mspace_slam
///     r = mspace_slam.run()
///     print(r["metrics"]["ate_rmse_m"], r["trajectory"].shape)
#[pymodule]
fn mspace_slam(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
