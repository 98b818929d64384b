#!/usr/bin/env bash
# Set-up and entry point. Usage:
#   bash run.sh demo   # set up .venv, then fit the embedded demo clip and write its outputs to demo_out/
#   bash run.sh test   # set up .venv (+ .venv-bpy5), lint, run the suite on every core; add-on tests on bpy 4.5 and 5.0
#   bash run.sh test --slow   # the same for the tests marked slow (end-to-end fits) that the line above leaves out
#   bash run.sh test --all    # both
# Set-up is idempotent: the venv is (re)built only when the requirements or their pinned versions change.
set -euo pipefail
cd "$(dirname "$0")"

PY="${NEURAL_ATLAS_PYTHON:-}"
if [ -z "$PY" ]; then
  for c in python3.11 python3; do
    if command -v "$c" >/dev/null 2>&1; then PY="$c"; break; fi
  done
fi
[ -n "$PY" ] || { echo "error: no python3 found — install Python 3.11" >&2; exit 2; }

# The engine's requirements are engine/requirements.txt and engine/requirements-farm.txt (ranges, also the wheel's);
# the development ones (the test tools, bpy 4.5) tests/requirements.txt, and Blender 5.0's venv
# tests/requirements-bpy5.txt: each installed with the exact versions of engine/constraints.txt.
CONSTRAINTS="engine/constraints.txt"

# pip without its wheel cache (a fresh machine installs once; the cache would hold a second copy of torch and bpy,
# ~1 GB), resuming an interrupted download many times, and the whole install tried a second time after a pause:
# a dropped connection to the package registry is the usual reason a fresh set-up fails
pip_install() {
  local py="$1"; shift
  local opts=(--quiet --no-cache-dir)
  local help
  help="$("$py" -m pip install --help 2>/dev/null || true)"
  [[ "$help" != *--resume-retries* ]] || opts+=(--resume-retries 30)
  "$py" -m pip install "${opts[@]}" "$@" && return 0
  echo "== pip install failed; trying once more in 30 s" >&2
  sleep 30
  "$py" -m pip install "${opts[@]}" "$@"
}
REQS="$(cat engine/requirements.txt engine/requirements-farm.txt tests/requirements.txt)"
STAMP=".venv/.requirements.sha256"
WANT="$(printf '%s\n' "$REQS" | cat - "$CONSTRAINTS" | sha256sum | cut -d' ' -f1)"
if [ ! -x .venv/bin/python ] || [ "$(cat "$STAMP" 2>/dev/null)" != "$WANT" ]; then
  echo "== setting up .venv (engine/requirements*.txt and the test tools, at the versions of $CONSTRAINTS)" >&2
  [ -x .venv/bin/python ] || "$PY" -m venv .venv
  # shellcheck disable=SC2086
  printf '%s\n' "$REQS" > .venv/requirements.txt
  .venv/bin/python -m pip install --quiet --no-cache-dir --upgrade pip >/dev/null 2>&1 || true
  pip_install .venv/bin/python -r .venv/requirements.txt -c "$CONSTRAINTS"
  echo "$WANT" > "$STAMP"
fi

# Blender 5.0 for the add-on tests: a second venv (bpy 4.5 lives in .venv; one bpy per interpreter).
BPY5_REQS="$(cat tests/requirements-bpy5.txt)"
setup_bpy5() {
  local want
  want="$(printf '%s\n' "$BPY5_REQS" | cat - "$CONSTRAINTS" | sha256sum | cut -d' ' -f1)"
  if [ ! -x .venv-bpy5/bin/python ] || [ "$(cat .venv-bpy5/.requirements.sha256 2>/dev/null)" != "$want" ]; then
    echo "== setting up .venv-bpy5 (bpy 5.0.1 for the add-on tests)" >&2
    [ -x .venv-bpy5/bin/python ] || "$PY" -m venv .venv-bpy5
    printf '%s\n' "$BPY5_REQS" > .venv-bpy5/requirements.txt
    .venv-bpy5/bin/python -m pip install --quiet --no-cache-dir --upgrade pip >/dev/null 2>&1 || true
    grep -v '^bpy==' "$CONSTRAINTS" > .venv-bpy5/constraints.txt  # the same versions, less .venv's bpy 4.5
    pip_install .venv-bpy5/bin/python -r .venv-bpy5/requirements.txt -c .venv-bpy5/constraints.txt
    echo "$want" > .venv-bpy5/.requirements.sha256
  fi
}

case "${1:-}" in
  demo)
    shift
    exec .venv/bin/python -m engine demo --out demo_out "$@"
    ;;
  test)
    shift
    # which tests: the default leaves out those marked slow (pyproject.toml's markers); CI runs both sets
    marks=(-m "not slow")
    case "${1:-}" in
      --slow) marks=(-m slow); shift ;;
      --all) marks=(); shift ;;
    esac
    .venv/bin/ruff check .
    .venv/bin/mypy  # the files listed in pyproject.toml's [tool.mypy]
    setup_bpy5
    rc=0
    # -n auto: a worker per core, a test file per worker at a time (its module fixtures are made once);
    # --durations: the slowest tests listed after every run, so what the suite costs stays in view
    par=(-n auto --dist loadfile)
    .venv/bin/python -m pytest -q "${par[@]}" --durations=25 "${marks[@]}" "$@" || rc=$?
    # the add-on tests again on Blender 5.0 (all of them, or the add-on paths among the arguments), less
    # tests/addon/core: pure Python without bpy, the same under any Blender; engine processes they start use .venv's
    bpy5_args=()
    if [ $# -eq 0 ]; then bpy5_args=(tests/addon --ignore=tests/addon/core); else
      for a in "$@"; do case "$a" in tests/addon*) bpy5_args+=("$a") ;; esac; done
    fi
    if [ ${#bpy5_args[@]} -gt 0 ]; then
      echo "== add-on tests on bpy 5.0.1 (.venv-bpy5)" >&2
      NEURAL_ATLAS_TEST_ENGINE_PYTHON="$PWD/.venv/bin/python" .venv-bpy5/bin/python -m pytest -q "${par[@]}" \
        "${marks[@]}" "${bpy5_args[@]}" || rc=$?
    fi
    exit $rc
    ;;
  *)
    echo "usage: bash run.sh demo | test [--slow | --all] [pytest arguments]" >&2
    exit 2
    ;;
esac
