"""docs/python-loop.py, the loop as a notebook runs it, on the paper's 99 groups of a machine
with two effects: it names both, ends at `none` near the data's floor, and writes the twin."""

import json
import os
import subprocess
import sys

from conftest import ROOT


def test_the_notebook_example_runs_the_whole_loop(cli, tmp_path):
    out = tmp_path / "out"
    env = dict(os.environ, STS_TWIN_CLI=cli)
    done = subprocess.run([sys.executable, str(ROOT / "docs" / "python-loop.py"), "--out", str(out)],
                          capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "stop: none" in done.stdout, done.stdout
    twin = json.loads((out / "twin.json").read_text())
    assert sorted(e["effect"] for e in twin["effects"]) == ["axis-coupling", "thermal-drift"]
    ladder = (out / "ladder.csv").read_text().splitlines()
    assert len(ladder) == 3 and ladder[0].startswith("effect,")
    assert "_error_um(const double f[12], double theta_rad)" in (out / "twin.h").read_text()
