"""Bad data and long calls from Python: a mixed dataset or a value no sensor produces is an
StsTwinError naming the file (never a PanicException), Ctrl-C stops a fit within a second as
KeyboardInterrupt, and a progress callback sees the searches."""

import json
import pathlib
import shutil
import subprocess
import sys
import textwrap

import pytest

import sts_twin
from conftest import run


@pytest.fixture(scope="module")
def small(cli, tmp_path_factory) -> pathlib.Path:
    """8 groups: 4 speeds, 2 strokes."""
    out = tmp_path_factory.mktemp("untrusted") / "small"
    run(cli, "measure", "--out", str(out), "--freqs", "5,10,20,30", "--amps", "1,5", "--quiet")
    return out


def test_a_mixed_dataset_is_refused(cli, small, tmp_path):
    other = tmp_path / "other"
    run(cli, "measure", "--out", str(other), "--freqs", "5,10,20,30", "--amps", "1,5", "--seed", "9", "--quiet")
    mixed = tmp_path / "mixed"
    shutil.copytree(small, mixed)
    shutil.copy(other / "g003.csv", mixed / "g003.csv")
    with pytest.raises(sts_twin.StsTwinError, match="g003.csv: not the file the manifest describes"):
        sts_twin.read_dataset(mixed)


def test_a_value_no_sensor_produces_is_refused(small, tmp_path):
    data = tmp_path / "huge"
    shutil.copytree(small, data)
    manifest = json.loads((data / "manifest.json").read_text())
    for g in manifest["groups"]:
        del g["rows"], g["crc32"]
    (data / "manifest.json").write_text(json.dumps(manifest))
    lines = (data / "g003.csv").read_text().splitlines()
    column = lines[0].split(",").index("z_tcp_um")
    fields = lines[47998].split(",")
    fields[column] = "1e308"
    lines[47998] = ",".join(fields)
    (data / "g003.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(sts_twin.StsTwinError, match=r"g003.csv:47999:\d+: column `z_tcp_um`: 1e308 is beyond"):
        sts_twin.read_dataset(data)


def test_progress_is_reported_and_an_exception_from_it_stops_the_fit(small):
    data = sts_twin.read_dataset(small)
    seen = []

    def progress(message, done, total):
        seen.append((message, done, total))
        if len(seen) == 3:
            raise RuntimeError("enough")

    with pytest.raises(RuntimeError, match="enough"):
        sts_twin.fit(data, epochs=100000, progress=progress)
    assert len(seen) == 3 and seen[0][2] == 12 and "search" in seen[0][0]


def test_ctrl_c_stops_a_fit_within_a_second(small):
    script = textwrap.dedent(
        f"""
        import os, signal, sys, threading, time
        import sts_twin
        data = sts_twin.read_dataset({str(small)!r})
        started = threading.Event()
        sent = []
        def interrupt():
            started.wait(30)
            sent.append(time.monotonic())
            os.kill(os.getpid(), signal.SIGINT)
        threading.Thread(target=interrupt, daemon=True).start()
        try:
            sts_twin.fit(data, epochs=100000, progress=lambda *a: started.set())
        except KeyboardInterrupt:
            print(time.monotonic() - sent[0])
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert float(done.stdout) < 1.0, done.stdout
