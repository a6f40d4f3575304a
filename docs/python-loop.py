# %% [markdown]
# # The lab's loop from Python
#
# A machine measured once, a twin fitted on that measurement, the missing physical effects
# named one after the other until what is left is the data's own noise, and the twin written
# for the firmware. Each `# %%` cell runs as a notebook cell (Jupyter, VS Code); as a script:
#
#     python docs/python-loop.py [DATASET] [--out DIR]
#
# Without DATASET, the cell below measures the emulated machine with two effects (thermal
# drift and an axis coupling) with `sts-twin measure`, as a lab would measure its own.
# CI runs this script (host-tools/python/tests/test_example.py).

# %%
import argparse
import os
import shutil
import subprocess
import sys

import sympy

import sts_twin

parser = argparse.ArgumentParser(description=__doc__)
parser.add_argument("dataset", nargs="?", help="a dataset directory (sts-twin-dataset/1)")
parser.add_argument("--out", default="python-loop-out", help="where the twin and the tables go")
parser.add_argument("--epochs", type=int, default=10, help="epoch limit per formula search")
args = parser.parse_args([] if "ipykernel" in sys.modules else None)
os.makedirs(args.out, exist_ok=True)

if args.dataset is None:
    cli = os.environ.get("STS_TWIN_CLI") or shutil.which("sts-twin") or "target/release/sts-twin"
    args.dataset = os.path.join(args.out, "machine")
    measure = [cli, "measure", "--out", args.dataset, "--effect", "thermal-drift", "--effect", "axis-coupling"]
    subprocess.run(measure + ["--seed", "21", "--quiet"], check=True)

# %% [markdown]
# ## The measurement
# One row per group of the test (a steady sine of the command), and any group's samples.

# %%
data = sts_twin.read_dataset(args.dataset)
print(data)
print(data.groups.head())
print(data.group(0).describe().T[["mean", "std", "min", "max"]])

# %% [markdown]
# ## A first twin, fitted on the data itself
# The amplitude and phase formulas (features f1..f12 to um and degrees) as SymPy expressions.

# %%
twin = sts_twin.fit(data, epochs=args.epochs)
print(twin)
formulas = twin.formulas()
print("amplitude_um =", sympy.simplify(formulas["amplitude_um"]))
print("phase_deg    =", formulas["phase_deg"])

# %% [markdown]
# ## Where it fails, and what is missing

# %%
comparison = sts_twin.compare(data, twin)
print(comparison)
print(comparison.groups.nlargest(5, "waveform_rms_um")[["file", "freq_hz", "amp_um", "waveform_rms_um"]])
diagnosis = sts_twin.diagnose(data, twin)
print(diagnosis.verdict)
print(diagnosis.ranking[["effect", "explained_fraction", "p_value", "significant"]].head())

# %% [markdown]
# ## The loop, run by itself
# Fit, diagnose, add the named effect, refit; until `none`: the residual is at the data's
# floor (what does not repeat from one period to the next).

# %%
ladder = sts_twin.explain(data, epochs=args.epochs)
print(ladder.steps[["effect", "explained_fraction", "waveform_rms_um_before", "waveform_rms_um_after"]])
print("stop:", ladder["stop"])
print(f"final: {ladder['waveform_rms_um'] * 1e3:.1f} nm held out; the data's floor {ladder['floor_um'] * 1e3:.1f} nm")
for effect in ladder.model.effects:
    print(effect["effect"], effect["params"])

# %% [markdown]
# ## The twin, for the board and for the tools a lab already has
# `sts-twin board upload` takes the model file; the C header compiles into a controller.

# %%
ladder.model.save(os.path.join(args.out, "twin.json"))
with open(os.path.join(args.out, "twin.h"), "w", encoding="utf-8") as f:
    f.write(ladder.model.export("c", name="sts_twin"))
ladder.steps.to_csv(os.path.join(args.out, "ladder.csv"), index=False)
print("not in the formulas (the firmware runs them):", ladder.model.not_exported)
print("twin written to", os.path.join(args.out, "twin.json"))
