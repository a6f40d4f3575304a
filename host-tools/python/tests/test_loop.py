"""The Python package gives what the CLI gives, bit for bit: the dataset as its files hold it,
the twin's model file byte for byte, and compare, diagnose and explain as their --json."""

import json
import math

import numpy as np
import pandas as pd
import pytest
import sympy

import sts_twin
from conftest import run

EPOCHS = "10"


def cli_json(cli, *args):
    return json.loads(run(cli, *args, "--json").stdout)


def test_the_dataset_reads_as_its_files_hold_it(cli, machine, tmp_path):
    data = sts_twin.read_dataset(machine)
    manifest = json.loads((machine / "manifest.json").read_text())
    assert len(data) == 24 and data.sample_rate_hz == manifest["sample_rate_hz"]
    assert data.groups.to_dict("records") == manifest["groups"]
    for index in (0, 23):
        samples = data.group(index)
        on_disk = pd.read_csv(machine / manifest["groups"][index]["file"])
        assert list(samples.columns) == list(on_disk.columns)
        pd.testing.assert_frame_equal(samples, on_disk, check_exact=True, check_dtype=False)
    # The training table is `fit --table`'s, value for value.
    table = tmp_path / "table.csv"
    run(cli, "fit", str(machine), "--table", str(table))
    pd.testing.assert_frame_equal(data.features(), pd.read_csv(table), check_exact=True)


def test_fit_writes_the_clis_twin_byte_for_byte(cli, machine, tmp_path):
    data = sts_twin.read_dataset(machine)
    for effects in ([], ["thermal-drift"]):
        out = tmp_path / "cli.json"
        flags = ["--effect", ",".join(effects)] if effects else []
        run(cli, "fit", str(machine), "--out", str(out), "--epochs", EPOCHS, "--seed", "3", "--quiet", "--force", *flags)
        twin = sts_twin.fit(data, effects=effects, epochs=int(EPOCHS), seed=3)
        assert twin.to_json() == out.read_text(), effects
        assert [e["effect"] for e in twin.effects] == effects
        # save and load give the same file back
        twin.save(tmp_path / "py.json")
        assert (tmp_path / "py.json").read_text() == out.read_text()
        assert sts_twin.Model.load(out).to_json() == out.read_text()
    # The result does not depend on the worker threads.
    one = sts_twin.fit(data, epochs=int(EPOCHS), threads=1)
    assert one.to_json() == sts_twin.fit(data, epochs=int(EPOCHS), threads=2).to_json()


def test_compare_and_diagnose_are_the_clis_json(cli, machine, tmp_path):
    out = tmp_path / "twin.json"
    run(cli, "fit", str(machine), "--out", str(out), "--epochs", EPOCHS, "--quiet")
    comparison = sts_twin.compare(machine, out)
    assert comparison.to_dict() == cli_json(cli, "compare", str(machine), "--model", str(out))
    assert len(comparison.groups) == 24 and comparison.waveform_rms_um > 0
    diagnosis = sts_twin.diagnose(machine, out)
    assert diagnosis.to_dict() == cli_json(cli, "diagnose", str(machine), "--model", str(out))
    assert diagnosis.verdict == diagnosis.ranking.iloc[0]["effect"] or diagnosis.verdict == "none"


def test_explain_is_the_clis_ladder_and_twin(cli, machine, tmp_path):
    # One step from nothing: the whole ladder to `none` runs in test_example.py, and each step
    # here costs a diagnosis and a refit twice (CLI and Python).
    out = tmp_path / "explained.json"
    expected = cli_json(cli, "explain", str(machine), "--out", str(out), "--epochs", EPOCHS, "--max-effects", "1")
    ladder = sts_twin.explain(machine, max_effects=1, epochs=int(EPOCHS))
    assert ladder.to_dict() == expected
    assert ladder.model.to_json() == out.read_text()
    assert list(ladder.steps["effect"]) == [s["effect"] for s in expected["steps"]]
    # From a given twin: the CLI's --model.
    base = tmp_path / "base.json"
    run(cli, "fit", str(machine), "--out", str(base), "--epochs", EPOCHS, "--quiet")
    expected = cli_json(cli, "explain", str(machine), "--model", str(base), "--out", str(out), "--force",
                        "--epochs", EPOCHS, "--max-effects", "1")
    ladder = sts_twin.explain(machine, model=base, max_effects=1, epochs=int(EPOCHS))
    assert ladder.to_dict() == expected and ladder.model.to_json() == out.read_text()


def test_the_formulas_as_sympy_are_the_hosts(machine):
    data = sts_twin.read_dataset(machine)
    twin = sts_twin.fit(data, epochs=int(EPOCHS))
    formulas = twin.formulas()
    features, theta = formulas["features"], formulas["theta"]
    assert [str(f) for f in features] == [f"f{i}" for i in range(1, 13)]
    assert formulas["error_um"].free_symbols <= set(features) | {theta}
    table = data.features()
    host = twin.evaluate(table)
    for name, column in (("amplitude_um", "amplitude_um"), ("phase_deg", "phase_deg")):
        f = sympy.lambdify(features, formulas[name], "math")
        ours = [f(*row) for row in table[[f"f{i}" for i in range(1, 13)]].itertuples(index=False)]
        np.testing.assert_allclose(ours, host[column], rtol=1e-12, atol=1e-12)
    # Eq. 4 at a quarter period: A sin(pi/2 + phi).
    row = dict(zip(features, table.iloc[0][[f"f{i}" for i in range(1, 13)]]))
    row[theta] = math.pi / 2
    a, phi = host.iloc[0]
    assert float(formulas["error_um"].subs(row)) == pytest.approx(a * math.cos(math.radians(phi)), rel=1e-12)


def test_bad_input_is_an_error_that_names_it(machine, tmp_path):
    with pytest.raises(sts_twin.StsTwinError, match="no-such-dataset"):
        sts_twin.read_dataset(tmp_path / "no-such-dataset")
    broken = tmp_path / "broken"
    broken.mkdir()
    manifest = json.loads((machine / "manifest.json").read_text())
    manifest["groups"][0]["freq_hz"] = "fast"
    (broken / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(sts_twin.StsTwinError, match="manifest.json"):
        sts_twin.read_dataset(broken)
    bad_model = tmp_path / "bad.json"
    bad_model.write_text('{"format": "sts-twin-model/1",\n "amplitude": }')
    with pytest.raises(sts_twin.StsTwinError, match=r"bad\.json:2:15: expected value"):
        sts_twin.Model.load(bad_model)
    with pytest.raises(sts_twin.StsTwinError, match="no-such-effect.*known: coulomb-friction"):
        sts_twin.fit(machine, effects=["no-such-effect"], epochs=1)
    assert len(sts_twin.EFFECTS) == 9 and "force-ripple" in sts_twin.EFFECTS
    assert sts_twin.SERVO_AXIS == "servo-axis" and sts_twin.SERVO_AXIS not in sts_twin.EFFECTS
    twin = sts_twin.fit(machine, epochs=1)
    with pytest.raises(sts_twin.StsTwinError, match="11 feature columns"):
        twin._native.evaluate([[1.0]] * 11)
    with pytest.raises(sts_twin.StsTwinError, match="group 24"):
        sts_twin.read_dataset(machine).group(24)
