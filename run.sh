#!/usr/bin/env bash
# Set-up and entry point. Usage:
#   bash run.sh demo   # set up .venv, then fit the embedded demo clip and write its outputs to demo_out/
#   bash run.sh test   # set up .venv, then lint and run the whole test suite
# Set-up is idempotent: the venv is (re)built only when the pinned requirements change.
set -euo pipefail
cd "$(dirname "$0")"

PY="${NEURAL_ATLAS_PYTHON:-}"
if [ -z "$PY" ]; then
  for c in python3.11 python3; do
    if command -v "$c" >/dev/null 2>&1; then PY="$c"; break; fi
  done
fi
[ -n "$PY" ] || { echo "error: no python3 found — install Python 3.11" >&2; exit 2; }

# The requirements are listed once, in engine/contract.py (stdlib-only, so any Python can read them).
REQS="$("$PY" -c 'import sys; sys.path.insert(0, "."); from engine import contract as c; print("\n".join(c.ENGINE_REQUIREMENTS + c.DEV_REQUIREMENTS))' 2>/dev/null \
  || "$PY" - <<'PYEOF'
import ast, pathlib
tree = ast.parse(pathlib.Path("engine/contract.py").read_text())
vals = {}
for node in tree.body:
    if isinstance(node, ast.AnnAssign) and node.target.id in ("ENGINE_REQUIREMENTS", "DEV_REQUIREMENTS"):
        vals[node.target.id] = ast.literal_eval(node.value)
print("\n".join(vals["ENGINE_REQUIREMENTS"] + vals["DEV_REQUIREMENTS"]))
PYEOF
)"
STAMP=".venv/.requirements.sha256"
WANT="$(printf '%s\n' "$REQS" | sha256sum | cut -d' ' -f1)"
if [ ! -x .venv/bin/python ] || [ "$(cat "$STAMP" 2>/dev/null)" != "$WANT" ]; then
  echo "== setting up .venv (pinned requirements from engine/contract.py)" >&2
  [ -x .venv/bin/python ] || "$PY" -m venv .venv
  # shellcheck disable=SC2086
  printf '%s\n' "$REQS" > .venv/requirements.txt
  .venv/bin/python -m pip install --quiet --upgrade pip >/dev/null 2>&1 || true
  .venv/bin/python -m pip install --quiet -r .venv/requirements.txt
  echo "$WANT" > "$STAMP"
fi

case "${1:-}" in
  demo)
    shift
    exec .venv/bin/python -m engine demo --out demo_out "$@"
    ;;
  test)
    shift
    .venv/bin/ruff check .
    exec .venv/bin/python -m pytest -q "$@"
    ;;
  *)
    echo "usage: bash run.sh demo | test" >&2
    exit 2
    ;;
esac
