#!/usr/bin/env bash
# Sets up the original DynEnv (github.com/szemenyeim/DynEnv, commit bb65ad3, GPLv3: run, never copied) for
# tools/original_benchmark.py, which times its soccer step beside ours (docs/benchmarks.md, "2v2 partial realistic,
# issue 42 part 4").
#
#   tools/original_benchmark.sh VENV CHECKOUT
#
# VENV: the folder of the original's own venv (made if missing; never this project's .venv). CHECKOUT: a checkout of
# the original at bb65ad3 (e.g. `git clone` of the repository above, then `git checkout bb65ad3`; a tree without
# .git is taken as it is). Needs a Python 3.8 interpreter: $PYTHON38, else python3.8 on PATH, else pyenv's 3.8.
# Installs what the original needs to step its environment (docs/original.md §0): pymunk 5.7.0 (it uses pymunk 5's
# API), numpy 1.21.6, gym 0.17.3, pygame 2.1.2, opencv-python-headless 4.5.5, and what its package imports at the
# top (imageio, matplotlib, pandas, cloudpickle); torch, which its package also imports but the environment never
# uses, is left out (tools/original_benchmark.py puts an empty module in its place). Then it checks the imports and
# prints the command that measures.
set -euo pipefail
if [ $# -ne 2 ]; then
    sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
fi
venv=$1
checkout=$2
if [ ! -f "$checkout/DynEnv/RoboCupEnvironment.py" ]; then
    echo "$checkout is not a checkout of DynEnv (no DynEnv/RoboCupEnvironment.py)" >&2
    exit 2
fi
if [ -d "$checkout/.git" ]; then
    at=$(git -C "$checkout" rev-parse --short=7 HEAD)
    if [ "$at" != "bb65ad3" ]; then
        echo "$checkout is at $at, not bb65ad3 (the commit docs/original.md describes): git checkout bb65ad3" >&2
        exit 2
    fi
fi
is38() { [ -n "$1" ] && "$1" -c 'import sys; assert sys.version_info[:2] == (3, 8)' 2>/dev/null; }
python=""
candidates=("${PYTHON38:-}" "$(command -v python3.8 || true)")
if command -v pyenv >/dev/null; then
    candidates+=("$(pyenv root)"/versions/3.8*/bin/python3.8)
fi
for candidate in "${candidates[@]}"; do
    if is38 "$candidate"; then
        python=$candidate
        break
    fi
done
if [ -z "$python" ]; then
    echo "no Python 3.8 found: set PYTHON38 to one (pymunk 5.7.0 and numpy 1.21.6 have no wheels for later ones)" >&2
    exit 2
fi
if [ ! -x "$venv/bin/python" ]; then
    "$python" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet "pymunk==5.7.0" "numpy==1.21.6" "gym==0.17.3" "pygame==2.1.2" \
    "opencv-python-headless==4.5.5.64" "imageio<2.28" "matplotlib<3.8" "pandas<2.1" "cloudpickle<2"
"$venv/bin/python" - "$checkout" <<'EOF'
import sys, types
sys.modules.setdefault("torch", types.ModuleType("torch"))
sys.path.insert(0, sys.argv[1])
from DynEnv import RoboCupEnvironment
import pymunk, numpy
print(f"the original imports: pymunk {pymunk.version}, numpy {numpy.__version__}, Python {sys.version.split()[0]}")
EOF
here=$(cd "$(dirname "$0")/.." && pwd)
echo "measure, interleaved with ours on core 1 (from $here):"
echo "  .venv/bin/python tools/original_benchmark.py interleave --original-python $venv/bin/python --dynenv $checkout --rounds 5 --out runs/original/2v2_partial.jsonl"
