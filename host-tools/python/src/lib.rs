#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

use std::path::{Path, PathBuf};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use sts_assess::explain::{Base, ExplainConfig};
use sts_fit::effects::EffectRecord;
use sts_fit::{FitConfig, StopFlag};
use sts_model::export::ExportLanguage;
use sts_model::ModelFile;
use sts_symreg::OperatorSet;

create_exception!(
    _native,
    StsTwinError,
    PyException,
    "What sts-twin refused or could not do: the message names the file, line and field, as the CLI's errors do."
);

/// A library error as the Python exception, with its causes (`a: b: c`, as the CLI prints them).
fn to_py<E: Into<anyhow::Error>>(error: E) -> PyErr {
    StsTwinError::new_err(sts_dataset::output::error_text(error.into().as_ref()))
}

/// What a panic says, for the error that reports it.
fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "a panic".into())
}

/// `work` as an [`StsTwinError`] where it panics (a bug): never a `PanicException`.
fn guarded<T>(work: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(work)).unwrap_or_else(|p| {
        Err(StsTwinError::new_err(format!("internal error (please report it): {}", panic_text(&*p))))
    })
}

/// What a long call reports to its thread: progress (message, done, total), then its result.
enum Report<T> {
    Progress(String, usize, Option<usize>),
    Done(std::thread::Result<anyhow::Result<T>>),
}

/// How a long call's work reports progress: (message, steps done, steps in all if known).
type Progress<'a> = &'a (dyn Fn(String, usize, Option<usize>) + Sync);

/// How often a long call looks for Ctrl-C and relays progress.
const POLL: Duration = Duration::from_millis(50);

/// Runs `work` on a thread of its own while this one, the caller's, relays its progress to
/// `progress` and looks for signals every [`POLL`]: a Ctrl-C (or an exception from
/// `progress`) sets `stop` and raises at once (`KeyboardInterrupt`); the work ends at its next
/// check of `stop` (a fit's searches at their next epoch), or runs out unseen where it has
/// none (a diagnosis, seconds). A panic in the work is an [`StsTwinError`].
fn run_long<T: Send + 'static>(
    py: Python<'_>,
    progress: Option<&Bound<'_, PyAny>>,
    stop: StopFlag,
    work: impl FnOnce(Progress) -> anyhow::Result<T> + Send + 'static,
) -> PyResult<T> {
    let (sender, mut receiver) = mpsc::channel::<Report<T>>();
    let progress_sender = sender.clone();
    std::thread::spawn(move || {
        let report = move |message: String, done: usize, total: Option<usize>| {
            let _ = progress_sender.send(Report::Progress(message, done, total));
        };
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| work(&report)));
        let _ = sender.send(Report::Done(result));
    });
    let interrupted = |error: PyErr| {
        stop.stop();
        Err(error)
    };
    loop {
        let (message, back) = py.detach(move || (receiver.recv_timeout(POLL), receiver));
        receiver = back;
        match message {
            Ok(Report::Progress(text, done, total)) => {
                if let Some(callback) = progress
                    && let Err(error) = callback.call1((text, done, total))
                {
                    return interrupted(error);
                }
            }
            Ok(Report::Done(Ok(result))) => return result.map_err(to_py),
            Ok(Report::Done(Err(panic))) => {
                return Err(StsTwinError::new_err(format!(
                    "internal error (please report it): {}",
                    panic_text(&*panic)
                )))
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err(StsTwinError::new_err("internal error (please report it): the work ended without a result"))
            }
        }
        if let Err(error) = py.check_signals() {
            return interrupted(error);
        }
    }
}

/// A measurement in the canonical dataset format, resampled to the servo rate as the CLI reads it.
#[pyclass(module = "sts_twin._native", name = "Dataset", frozen)]
struct PyDataset {
    dataset: Arc<sts_dataset::Dataset>,
    /// The directory's name (the model file's description names it, never the whole path).
    name: String,
}

#[pymethods]
impl PyDataset {
    /// Reads the dataset in directory `path` (sts-twin-dataset/1).
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let dataset = guarded(|| py.detach(|| sts_analysis::read_dataset(&path)).map_err(to_py))?;
        Ok(Self { dataset: Arc::new(dataset), name: dataset_name(&path) })
    }

    /// The directory's name.
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }

    /// The manifest as JSON (format, sample rate, description, the groups).
    fn manifest_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.dataset.manifest).map_err(to_py)
    }

    /// Group `index`'s channels: (column name, its samples as little-endian f64 bytes), in the
    /// dataset format's column order; optional columns only where the group has them.
    fn columns<'py>(&self, py: Python<'py>, index: usize) -> PyResult<Vec<(&'static str, Bound<'py, PyBytes>)>> {
        let group = self.dataset.groups.get(index).ok_or_else(|| {
            StsTwinError::new_err(format!(
                "group {index} is not in {} ({} groups)",
                self.name,
                self.dataset.groups.len()
            ))
        })?;
        Ok(sts_dataset::Column::ALL
            .into_iter()
            .filter_map(|c| group.column(c).map(|v| (c.name(), v)))
            .map(|(name, values)| {
                let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                (name, PyBytes::new(py, &bytes))
            })
            .collect())
    }

    /// The training table, as `fit --table` writes it: per group the 12 features and the
    /// measured amplitude and phase.
    #[pyo3(signature = (acc_scale=None, skip_s=None))]
    fn training_table_csv(&self, py: Python<'_>, acc_scale: Option<f64>, skip_s: Option<f64>) -> PyResult<String> {
        let skip_s = skip_s.unwrap_or(sts_analysis::DEFAULT_SKIP_S);
        py.detach(|| {
            let config = sts_analysis::feature_config_for(&self.dataset, acc_scale);
            sts_analysis::group_samples_skipping(&self.dataset, &config, skip_s)
                .map(|samples| sts_analysis::training_table_csv(&samples))
        })
        .map_err(to_py)
    }
}

/// The dataset directory's name (not its full path: model files carry no machine paths), as
/// `sts-twin fit` names it.
fn dataset_name(path: &Path) -> String {
    path.canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| path.display().to_string())
}

/// A twin: the model file and, where it has one, its `effects` field.
#[pyclass(module = "sts_twin._native", name = "Model", frozen)]
struct PyModel {
    model: ModelFile,
    /// `None` where the file has no `effects` field (a fit without effects writes none).
    effects: Option<Vec<EffectRecord>>,
}

impl PyModel {
    /// The model file's text parsed and checked, with its `effects` field.
    fn parse(text: &str) -> PyResult<Self> {
        let model = ModelFile::from_json(text).map_err(to_py)?;
        let value: serde_json::Value = serde_json::from_str(text).map_err(to_py)?;
        let effects = match value.get("effects") {
            Some(v) => Some(
                serde_json::from_value(v.clone())
                    .map_err(|e| StsTwinError::new_err(format!("the model's `effects` field: {e}")))?,
            ),
            None => None,
        };
        Ok(Self { model, effects })
    }
}

#[pymethods]
impl PyModel {
    /// Parses and checks the text of a model file (sts-twin-model/1).
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        guarded(|| Self::parse(text))
    }

    /// Reads and checks a model file (bounded in size as the CLI reads it).
    #[staticmethod]
    fn read(path: PathBuf) -> PyResult<Self> {
        guarded(|| {
            ModelFile::read(&path).map_err(to_py)?;
            let text = std::fs::read_to_string(&path).map_err(|e| to_py(anyhow::anyhow!("{}: {e}", path.display())))?;
            Self::parse(&text).map_err(|e| StsTwinError::new_err(format!("{}: {}", path.display(), e)))
        })
    }

    /// Writes the model file whole or not at all (a temporary file beside it, then a rename).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        let text = self.to_json()?;
        sts_dataset::output::write_file(&path, text.as_bytes()).map_err(to_py)
    }

    /// The model file's text, byte for byte what the CLI writes for the same twin.
    fn to_json(&self) -> PyResult<String> {
        match &self.effects {
            None => serde_json::to_string_pretty(&self.model).map(|t| t + "\n").map_err(to_py),
            Some(records) => sts_fit::effects::model_text_with_records(&self.model, records).map_err(to_py),
        }
    }

    /// The firmware program's id (as `fit` prints it).
    #[getter]
    fn program_id(&self) -> u32 {
        self.model.program.id
    }

    /// The effects the twin carries, as its file's `effects` field holds them (JSON, `[]` where
    /// the file has none).
    fn effects_json(&self) -> PyResult<String> {
        serde_json::to_string(self.effects.as_deref().unwrap_or_default()).map_err(to_py)
    }

    /// The amplitude (um) and phase (degrees) formulas evaluated in f64 on `features`: the 12
    /// columns f1..f12, one value per row each.
    fn evaluate(&self, features: Vec<Vec<f64>>) -> PyResult<(Vec<f64>, Vec<f64>)> {
        let n = sts_twin_core::features::FEATURE_LABELS.len();
        if features.len() != n {
            return Err(StsTwinError::new_err(format!(
                "{} feature columns given, the formulas take {n} (f1..f{n})",
                features.len()
            )));
        }
        let rows = features[0].len();
        if let Some(i) = features.iter().position(|c| c.len() != rows) {
            return Err(StsTwinError::new_err(format!("f{} has {} rows, f1 has {rows}", i + 1, features[i].len())));
        }
        let columns: Vec<&[f64]> = features.iter().map(Vec::as_slice).collect();
        let eval = |formula: &sts_model::Formula, what: &str| {
            formula.expr.eval_columns(&columns).ok_or_else(|| {
                StsTwinError::new_err(format!("the {what} formula is not finite on some row of these features"))
            })
        };
        Ok((eval(&self.model.amplitude, "amplitude")?, eval(&self.model.phase, "phase")?))
    }

    /// The formulas (and Eq. 4) in `language` (c, matlab, sympy or latex), as
    /// `sts-twin export` writes them: (text, the per-tick terms left out).
    fn export(&self, language: &str, name: &str, origin: &str) -> PyResult<(String, Vec<String>)> {
        let language: ExportLanguage = language.parse().map_err(StsTwinError::new_err)?;
        let out = sts_model::export::export(&self.model, language, name, origin).map_err(to_py)?;
        Ok((out.text, out.not_exported))
    }
}

/// A fit's progress as the progress callback takes it: (message, searches done, searches in all).
fn fit_progress(report: Progress<'_>) -> impl FnMut(&sts_fit::FitProgress) + '_ {
    move |p: &sts_fit::FitProgress| {
        let search = match p.fold {
            Some(fold) => format!("{:?} search of fold {fold}", p.target),
            None => format!("final {:?} search", p.target),
        };
        report(format!("{search}, epoch {}: {}", p.epoch, p.best), p.searches_done, Some(p.searches_total));
    }
}

/// Fits a twin on `dataset`, with `effects`' per-tick terms, as `sts-twin fit` does. Ctrl-C
/// stops it (`KeyboardInterrupt`); `progress(message, done, total)` is called as searches report.
#[pyfunction]
#[pyo3(signature = (dataset, effects=Vec::new(), seed=0, threads=None, epochs=None, folds=None, operators=None, max_complexity=None, acc_scale=None, skip_s=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn fit(
    py: Python<'_>,
    dataset: &PyDataset,
    effects: Vec<String>,
    seed: u64,
    threads: Option<usize>,
    epochs: Option<usize>,
    folds: Option<usize>,
    operators: Option<&str>,
    max_complexity: Option<usize>,
    acc_scale: Option<f64>,
    skip_s: Option<f64>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<PyModel> {
    // `None` takes the CLI's default.
    let d = FitConfig::default();
    let operators = match operators {
        Some(text) => {
            OperatorSet::parse(text).map_err(|e| StsTwinError::new_err(format!("operators {text:?}: {e}")))?
        }
        None => d.operators.clone(),
    };
    let skip_s = skip_s.unwrap_or(d.skip_s);
    if !(skip_s.is_finite() && skip_s >= 0.0) {
        return Err(StsTwinError::new_err(format!("skip_s must be zero or positive, not {skip_s}")));
    }
    let stop = StopFlag::new();
    let config = FitConfig {
        seed,
        threads: threads.unwrap_or(d.threads).max(1),
        max_epochs: epochs.unwrap_or(d.max_epochs),
        folds: folds.unwrap_or(d.folds),
        operators,
        max_complexity: max_complexity.unwrap_or(d.max_complexity),
        acc_scale_override: acc_scale,
        skip_s,
        stop: Some(stop.clone()),
        ..d
    };
    let description = format!("fitted by sts-twin fit on {} (seed {seed})", dataset.name);
    let data = Arc::clone(&dataset.dataset);
    run_long(py, progress.as_ref(), stop, move |report| {
        let mut on_progress = fit_progress(report);
        if effects.is_empty() {
            let model = sts_fit::fit(&data, &description, &config, &mut on_progress)?;
            Ok(PyModel { model, effects: None })
        } else {
            let (model, records) =
                sts_fit::effects::fit_with(&data, &effects, &description, &config, &mut on_progress)?;
            Ok(PyModel { model, effects: Some(records) })
        }
    })
}

/// Compares `model` with `dataset`, group by group: the JSON of `sts-twin compare --json`.
#[pyfunction]
#[pyo3(signature = (dataset, model, progress=None))]
fn compare(
    py: Python<'_>,
    dataset: &PyDataset,
    model: &PyModel,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    one_step(py, dataset, model, progress, ("comparing", "compared"), |data, model| {
        let (c, _) = sts_assess::compare::compare(data, model)?;
        Ok(serde_json::to_string(&sts_assess::json::comparison(&c)?)?)
    })
}

/// Which physical effect `model` misses on `dataset`: the JSON of `sts-twin diagnose --json`.
/// Ctrl-C raises `KeyboardInterrupt` at once (the diagnosis, seconds, runs out unseen).
#[pyfunction]
#[pyo3(signature = (dataset, model, progress=None))]
fn diagnose(
    py: Python<'_>,
    dataset: &PyDataset,
    model: &PyModel,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    one_step(py, dataset, model, progress, ("diagnosing", "diagnosed"), |data, model| {
        let d = sts_assess::diagnose::diagnose(data, model)?;
        Ok(serde_json::to_string(&sts_assess::json::diagnosis(&d, data))?)
    })
}

/// One step on `dataset` and `model` whose result is JSON (compare, diagnose), in the
/// background as every long call is ([`run_long`]): `progress` hears `stage.0` before it and
/// `stage.1` after.
fn one_step(
    py: Python<'_>,
    dataset: &PyDataset,
    model: &PyModel,
    progress: Option<Bound<'_, PyAny>>,
    stage: (&'static str, &'static str),
    work: impl FnOnce(&sts_dataset::Dataset, &ModelFile) -> anyhow::Result<String> + Send + 'static,
) -> PyResult<String> {
    let (data, model) = (Arc::clone(&dataset.dataset), model.model.clone());
    run_long(py, progress.as_ref(), StopFlag::new(), move |report| {
        report(stage.0.into(), 0, Some(1));
        let json = work(&data, &model)?;
        report(stage.1.into(), 1, Some(1));
        Ok(json)
    })
}

/// The lab's loop run by itself, as `sts-twin explain` runs it: the JSON of `--json` and the
/// final twin. Ctrl-C stops it (`KeyboardInterrupt`); `progress(message, step, None)` is
/// called at each fit and diagnosis.
#[pyfunction]
#[pyo3(signature = (dataset, model=None, max_effects=4, seed=0, epochs=None, progress=None))]
fn explain(
    py: Python<'_>,
    dataset: &PyDataset,
    model: Option<&PyModel>,
    max_effects: usize,
    seed: u64,
    epochs: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<(String, PyModel)> {
    let d = FitConfig::default();
    let stop = StopFlag::new();
    let config = ExplainConfig {
        fit: FitConfig { seed, max_epochs: epochs.unwrap_or(d.max_epochs), stop: Some(stop.clone()), ..d },
        max_effects,
    };
    let base = model.map(|m| Base { model: m.model.clone(), effects: m.effects.clone().unwrap_or_default() });
    let description = format!("fitted by sts-twin explain on {} (seed {seed})", dataset.name);
    let data = Arc::clone(&dataset.dataset);
    run_long(py, progress.as_ref(), stop, move |report| {
        let mut step = 0;
        let mut on_progress = |p: sts_assess::explain::ExplainProgress| {
            use sts_assess::explain::ExplainProgress;
            let text = match p {
                ExplainProgress::Fitting => "fitting a twin on the data".to_string(),
                ExplainProgress::Diagnosing { effects } => format!("diagnosing the twin with [{}]", effects.join(", ")),
                ExplainProgress::Refitting { effects } => format!("fitting a twin with [{}]", effects.join(", ")),
            };
            report(text, step, None);
            step += 1;
        };
        let e = sts_assess::explain::explain(&data, &description, base, &config, &mut on_progress)?;
        let json = serde_json::to_string(&sts_assess::json::explanation(&e))?;
        Ok((json, PyModel { model: e.model, effects: Some(e.effects) }))
    })
}

/// The native part of the `sts_twin` Python package.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("StsTwinError", m.py().get_type::<StsTwinError>())?;
    m.add_class::<PyDataset>()?;
    m.add_class::<PyModel>()?;
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(explain, m)?)?;
    m.add("EFFECTS", sts_model::Effect::ALL.map(sts_model::Effect::name))?;
    m.add("SERVO_AXIS", sts_model::SERVO_AXIS)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
