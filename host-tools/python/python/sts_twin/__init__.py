"""sts-twin from Python: the lab's loop (read a measurement, fit a twin, compare, diagnose,
explain) on the same Rust libraries as the ``sts-twin`` command, with the same results bit for
bit, handed back as pandas tables and SymPy expressions.

    import sts_twin
    data = sts_twin.read_dataset("measurement")
    twin = sts_twin.fit(data)
    print(sts_twin.diagnose(data, twin).verdict)
    ladder = sts_twin.explain(data)
    ladder.model.save("twin.json")

Every figure is a Python float equal to the one the CLI prints with ``--json``; the model files
are byte for byte what ``sts-twin fit`` and ``sts-twin explain`` write.
"""

from __future__ import annotations

import io
import json
import os
from typing import Any, Callable, Iterable, Optional, Union

import numpy as np
import pandas as pd

from . import _native
from ._native import StsTwinError

__all__ = [
    "EFFECTS",
    "SERVO_AXIS",
    "Comparison",
    "Dataset",
    "Diagnosis",
    "Explanation",
    "Model",
    "StsTwinError",
    "compare",
    "diagnose",
    "explain",
    "fit",
    "read_dataset",
]
__version__ = _native.__version__

#: The physical effects' names, as ``fit(effects=...)``, the model files and the diagnoses use them.
EFFECTS: tuple[str, ...] = tuple(_native.EFFECTS)
#: ``fit(effects=[SERVO_AXIS])``: the servo-axis twin alone, the twin for a machine's whole speed range.
SERVO_AXIS: str = _native.SERVO_AXIS

PathLike = Union[str, "os.PathLike[str]"]

# A long call's progress: (message, steps done, steps in all or None where not known).
ProgressCallback = Callable[[str, int, Optional[int]], None]


class Dataset:
    """A measurement in the canonical dataset format (sts-twin-dataset/1), as the CLI reads
    it: a dataset sampled at another rate is resampled to the servo rate."""

    def __init__(self, path: PathLike):
        self.path = os.fspath(path)
        self._native = _native.Dataset(self.path)
        self.manifest: dict[str, Any] = json.loads(self._native.manifest_json())

    @property
    def name(self) -> str:
        """The directory's name."""
        return self._native.name

    @property
    def sample_rate_hz(self) -> float:
        return self.manifest["sample_rate_hz"]

    @property
    def groups(self) -> pd.DataFrame:
        """One row per group: file, freq_hz, amp_um, start_s."""
        return pd.DataFrame(self.manifest["groups"])

    def __len__(self) -> int:
        return len(self.manifest["groups"])

    def group(self, index: int) -> pd.DataFrame:
        """Group ``index``'s samples: t_s, z_cmd_um, z_enc_um, z_tcp_um, acc_mps2 and the
        optional channels it has (x_mm, x_acc_mps2, spindle_deg, temp_c)."""
        columns = self._native.columns(index)
        return pd.DataFrame({name: np.frombuffer(raw, dtype="<f8") for name, raw in columns})

    def features(self, acc_scale: Optional[float] = None, skip_s: Optional[float] = None) -> pd.DataFrame:
        """The training table (``sts-twin fit --table``): per group the 12 features f1..f12 and
        the measured amplitude (um) and phase (degrees) of its dynamic error."""
        text = self._native.training_table_csv(acc_scale, skip_s)
        return pd.read_csv(io.StringIO(text))

    def __repr__(self) -> str:
        return f"Dataset({self.path!r}: {len(self)} groups at {self.sample_rate_hz} Hz)"


def read_dataset(path: PathLike) -> Dataset:
    """Reads the dataset in directory ``path``."""
    return Dataset(path)


def _dataset(data: Union[Dataset, PathLike]) -> Dataset:
    return data if isinstance(data, Dataset) else Dataset(data)


class Model:
    """A twin: the model file (sts-twin-model/1) that ``fit`` and ``explain`` write and the
    firmware runs."""

    def __init__(self, native: "_native.Model"):
        self._native = native
        self._dict: Optional[dict[str, Any]] = None

    @classmethod
    def load(cls, path: PathLike) -> "Model":
        """Reads and checks a model file (at most a few MB, as the CLI reads it)."""
        return cls(_native.Model.read(os.fspath(path)))

    def to_json(self) -> str:
        """The model file's text: byte for byte what the CLI writes for the same twin."""
        return self._native.to_json()

    def save(self, path: PathLike) -> None:
        """Writes the model file whole or not at all (a temporary file beside it, then a
        rename over ``path``)."""
        self._native.save(os.fspath(path))

    def to_dict(self) -> dict[str, Any]:
        if self._dict is None:
            self._dict = json.loads(self.to_json())
        return self._dict

    @property
    def program_id(self) -> int:
        return self._native.program_id

    @property
    def effects(self) -> list[dict[str, Any]]:
        """The effects the twin carries, each with its parameters (name with unit: value)."""
        records = json.loads(self._native.effects_json())
        return [{"effect": r["effect"], "params": dict(r["params"]), "note": r["note"]} for r in records]

    @property
    def validation(self) -> pd.DataFrame:
        """The held-out validation, one row per group (the figures ``fit`` prints)."""
        return pd.DataFrame(self.to_dict()["validation"]["groups"])

    @property
    def waveform_rms_um(self) -> float:
        """Held-out waveform RMS over the training data, um."""
        return self.to_dict()["validation"]["waveform_rms_um"]

    def evaluate(self, features: pd.DataFrame) -> pd.DataFrame:
        """The amplitude (um) and phase (degrees) formulas evaluated in double precision on
        the columns f1..f12 of ``features`` (e.g. ``Dataset.features()``), one row per row."""
        columns = [np.asarray(features[f"f{i}"], dtype=float).tolist() for i in range(1, 13)]
        amp_um, phase_deg = self._native.evaluate(columns)
        return pd.DataFrame({"amplitude_um": amp_um, "phase_deg": phase_deg}, index=features.index)

    def export(self, language: str, name: str = "sts_twin", origin: str = "a Python session") -> str:
        """The formulas and Eq. 4 as ``sts-twin export --to LANGUAGE`` writes them (c, matlab,
        sympy or latex). Per-tick terms that only the firmware runs are named in the text."""
        text, _ = self._native.export(language, name, origin)
        return text

    @property
    def not_exported(self) -> list[str]:
        """The twin's per-tick terms, in words, that no formula export holds."""
        return self._native.export("sympy", "sts_twin", "")[1]

    def formulas(self) -> dict[str, Any]:
        """The formulas as SymPy expressions: ``amplitude_um`` and ``phase_deg`` in the features
        ``f1``..``f12``, ``error_um`` (Eq. 4) also in the command phase ``theta`` (radians),
        and the symbols (``features``, ``theta``). Constants keep every digit."""
        namespace: dict[str, Any] = {}
        exec(compile(self.export("sympy"), "<sts-twin formulas>", "exec"), namespace)
        keys = ("amplitude_um", "phase_deg", "error_um", "features", "theta", "not_exported")
        return {k: namespace[k] for k in keys}

    def __repr__(self) -> str:
        carried = ", ".join(e["effect"] for e in self.effects) or "no effects"
        return f"Model(program {self.program_id:08x}, {carried}, held out {self.waveform_rms_um * 1e3:.1f} nm)"


def _model(model: Union[Model, PathLike]) -> Model:
    return model if isinstance(model, Model) else Model.load(model)


def fit(
    data: Union[Dataset, PathLike],
    effects: Iterable[str] = (),
    seed: int = 0,
    threads: Optional[int] = None,
    epochs: Optional[int] = None,
    folds: Optional[int] = None,
    operators: Optional[str] = None,
    max_complexity: Optional[int] = None,
    acc_scale: Optional[float] = None,
    skip_s: Optional[float] = None,
    progress: Optional[ProgressCallback] = None,
) -> Model:
    """Fits a twin on ``data`` as ``sts-twin fit`` does, with ``effects``' per-tick terms
    (names of ``EFFECTS`` or ``SERVO_AXIS``, e.g. ``["coulomb-friction", "thermal-drift"]``). ``None`` takes the
    CLI's default; the same data, seed and settings give the same twin. Ctrl-C stops it
    within a second (``KeyboardInterrupt``); ``progress(message, searches_done,
    searches_total)`` is called as the searches report (an exception from it stops the fit)."""
    native = _native.fit(
        _dataset(data)._native,
        list(effects),
        seed,
        threads,
        epochs,
        folds,
        operators,
        max_complexity,
        acc_scale,
        skip_s,
        progress,
    )
    return Model(native)


class _Report:
    """A result as the CLI's ``--json`` prints it (``to_dict``), with tables beside it."""

    def __init__(self, text: str):
        self._dict: dict[str, Any] = json.loads(text)

    def to_dict(self) -> dict[str, Any]:
        return self._dict

    def __getitem__(self, key: str) -> Any:
        return self._dict[key]


class Comparison(_Report):
    """``sts-twin compare --json``: the summary and one row per group."""

    @property
    def groups(self) -> pd.DataFrame:
        return pd.DataFrame(self._dict["groups"])

    @property
    def waveform_rms_um(self) -> float:
        return self._dict["waveform_rms_um"]

    def __repr__(self) -> str:
        return f"Comparison(waveform RMS {self.waveform_rms_um * 1e3:.1f} nm over {len(self._dict['groups'])} groups)"


def compare(
    data: Union[Dataset, PathLike], model: Union[Model, PathLike], progress: Optional[ProgressCallback] = None
) -> Comparison:
    """Compares ``model`` with ``data`` group by group, as ``sts-twin compare`` does."""
    return Comparison(_native.compare(_dataset(data)._native, _model(model)._native, progress))


class Diagnosis(_Report):
    """``sts-twin diagnose --json``: the verdict, the candidates ranked, the test."""

    @property
    def verdict(self) -> str:
        return self._dict["verdict"]

    @property
    def ranking(self) -> pd.DataFrame:
        return pd.DataFrame(self._dict["ranking"])

    def __repr__(self) -> str:
        return f"Diagnosis(verdict {self.verdict!r}: {self._dict['summary']})"


def diagnose(
    data: Union[Dataset, PathLike], model: Union[Model, PathLike], progress: Optional[ProgressCallback] = None
) -> Diagnosis:
    """Which physical effect ``model`` misses on ``data``, as ``sts-twin diagnose`` says.
    Ctrl-C raises ``KeyboardInterrupt`` within a second."""
    return Diagnosis(_native.diagnose(_dataset(data)._native, _model(model)._native, progress))


class Explanation(_Report):
    """``sts-twin explain --json``: the ladder of effects, why it stopped, and the final twin
    (``model``)."""

    def __init__(self, text: str, model: Model):
        super().__init__(text)
        self.model = model

    @property
    def verdict(self) -> str:
        return self._dict["verdict"]

    @property
    def steps(self) -> pd.DataFrame:
        """One row per rung: effect, explained fraction, p-value, error before and after (um)."""
        columns = [
            "effect",
            "explained_fraction",
            "p_value",
            "waveform_rms_um_before",
            "waveform_rms_um_after",
            "evidence",
        ]
        return pd.DataFrame(self._dict["steps"], columns=columns)

    def __repr__(self) -> str:
        names = " -> ".join(s["effect"] for s in self._dict["steps"]) or "no effect"
        return f"Explanation({names}; {self.verdict}; {self._dict['waveform_rms_um'] * 1e3:.1f} nm)"


def explain(
    data: Union[Dataset, PathLike],
    model: Union[Model, PathLike, None] = None,
    max_effects: int = 4,
    seed: int = 0,
    epochs: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
) -> Explanation:
    """The lab's loop, as ``sts-twin explain`` runs it: fit a twin on ``data`` (or start from
    ``model``), diagnose, add the named effect, refit, until ``none`` or ``max_effects``.
    Ctrl-C stops it within a second (``KeyboardInterrupt``); ``progress(message, step,
    None)`` is called at each fit and diagnosis."""
    base = None if model is None else _model(model)._native
    text, native = _native.explain(_dataset(data)._native, base, max_effects, seed, epochs, progress)
    return Explanation(text, Model(native))
