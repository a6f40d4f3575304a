#!/usr/bin/env bash
# Times CI like for like: `.ci/run` on a fresh clone of HEAD whose `scripts/test.sh` runs only
# the Rust tests that existed at REV (and pytest only if REV had the Python package). Everything
# is still built, so an old commit's CI time compares with today's on the same tests
# (BENCHMARKS.md, "CI time").
#
#   bench/ci-same-tests.sh REV [CLONE_DIR]     (CLONE_DIR: ../ci-same-tests)
#
# A test is one of REV's when a `#[test]` function (or a proptest) of that name is in REV's
# tree; every other test of HEAD is passed to libtest as `--skip=NAME` (a substring filter:
# the script stops if a skipped name is part of a kept one).
set -euo pipefail
rev=${1:?usage: bench/ci-same-tests.sh REV [CLONE_DIR]}
repo=$(git rev-parse --show-toplevel)
dir=${2:-$repo/../ci-same-tests}
git -C "$repo" rev-parse --verify --quiet "$rev^{commit}" >/dev/null || {
    echo "error: $rev is not a commit of $repo" >&2
    exit 2
}
# Only a clone this script made is replaced (it holds the list of skipped tests).
if [ -e "$dir" ] && [ ! -f "$dir/scripts/tests-added-since.txt" ]; then
    echo "error: $dir exists and is not a clone made by this script: remove it or name another" >&2
    exit 2
fi
rm -rf "$dir"
git clone -q "$repo" "$dir"
cd "$dir"

python3 - "$rev" >scripts/tests-added-since.txt <<'EOF'
import re, subprocess, sys

def tests_at(rev):
    files = subprocess.run(["git", "ls-tree", "-r", "--name-only", rev],
                           capture_output=True, text=True, check=True).stdout.split()
    names = set()
    for path in (f for f in files if f.endswith(".rs")):
        src = subprocess.run(["git", "show", f"{rev}:{path}"],
                             capture_output=True, text=True, check=True).stdout
        lines = src.split("\n")
        for i, line in enumerate(lines):
            if re.match(r"\s*#\[test\]", line):
                for follow in lines[i + 1:i + 8]:
                    m = re.search(r"fn ([a-z_0-9]+)\s*\(", follow)
                    if m:
                        names.add(m.group(1))
                        break
        for block in re.finditer(r"proptest!\s*\{(.*?)\n\}", src, re.S):
            names.update(re.findall(r"fn ([a-z_0-9]+)\s*\(", block.group(1)))
    return names

kept, now = tests_at(sys.argv[1]), tests_at("HEAD")
added = sorted(now - kept)
clash = [(a, k) for a in added for k in kept & now if a in k]
if clash:
    sys.exit(f"error: skipping {clash[0][0]} would also skip {clash[0][1]}")
print("\n".join(added))
EOF

python3 - "$rev" <<'EOF'
import subprocess, sys
rev = sys.argv[1]
s = open("scripts/test.sh").read()
pytest = subprocess.run(["git", "cat-file", "-e", f"{rev}:host-tools/python"],
                        stderr=subprocess.DEVNULL).returncode == 0
edits = [
    ('step "tests that boot the firmware in QEMU',
     "mapfile -t skips < <(sed 's/^/--skip=/' scripts/tests-added-since.txt)\n"
     'step "tests that boot the firmware in QEMU'),
    ('-- --test-threads=1\n', '-- --test-threads=1 "${skips[@]}"\n'),
    ('-- "${assess_suites[@]}"\n', '-- "${assess_suites[@]}" "${skips[@]}"\n'),
    ('-- "${assess_suites[@]/#/--skip=}"\n', '-- "${assess_suites[@]/#/--skip=}" "${skips[@]}"\n'),
]
if not pytest:
    edits += [
        ('background "Python package: pytest against the CLI, docs/python-loop.py" '
         'bash scripts/python-package.sh test\n', ''),
        ('finish "Python package: pytest against the CLI, docs/python-loop.py"\n', ''),
    ]
for old, new in edits:
    if s.count(old) != 1:
        sys.exit(f"error: scripts/test.sh has changed: {old.strip()!r} is not there once")
    s = s.replace(old, new)
open("scripts/test.sh", "w").write(s)
EOF

echo "$(wc -l <scripts/tests-added-since.txt) tests of HEAD skipped (not at $rev): $dir/scripts/tests-added-since.txt"
/usr/bin/time -v bash .ci/run
