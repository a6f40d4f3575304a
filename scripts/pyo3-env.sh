# Sourced by scripts/test.sh and scripts/python-package.sh: the interpreter pyo3 builds for, and
# the signature maturin gives pyo3's build script for it. The test build and the wheel then
# share one build of pyo3 and the crates above it instead of each rebuilding the other's.
export PYO3_PYTHON PYO3_ENVIRONMENT_SIGNATURE
PYO3_PYTHON=${PYO3_PYTHON:-$(python3 -c 'import sys; print(sys.executable)')}
PYO3_ENVIRONMENT_SIGNATURE=$("$PYO3_PYTHON" -c 'import struct, sys
bits = struct.calcsize("P") * 8
print(f"{sys.implementation.name}-{sys.version_info[0]}.{sys.version_info[1]}-{bits}bit")')
