"""Fixtures: the `sts-twin` CLI the results are checked against, and emulator measurements
made with it (as a lab would make its own)."""

import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def cli() -> str:
    """The CLI binary: $STS_TWIN_CLI, else the root workspace's release build."""
    path = os.environ.get("STS_TWIN_CLI") or str(ROOT / "target" / "release" / "sts-twin")
    if not os.path.isfile(path):
        pytest.fail(f"no sts-twin CLI at {path}: build it with `cargo build --release -p sts-twin` (or set STS_TWIN_CLI)")
    return path


def run(cli: str, *args: str) -> subprocess.CompletedProcess:
    done = subprocess.run([cli, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"sts-twin {' '.join(args)}:\n{done.stderr}"
    return done


@pytest.fixture(scope="session")
def machine(cli, tmp_path_factory) -> pathlib.Path:
    """A machine with thermal drift and an axis coupling, measured on 24 groups (8 speeds,
    3 strokes): small enough that the loop runs in seconds."""
    out = tmp_path_factory.mktemp("data") / "machine"
    run(cli, "measure", "--out", str(out), "--effect", "thermal-drift", "--effect", "axis-coupling",
        "--seed", "21", "--freqs", "10,20,30,40,50,60,70,80", "--amps", "2,4,6", "--quiet")
    return out
