#!/usr/bin/env bash
# rigcal developer entry point: installs everything, then runs one job.
#
#   bash scripts/dev.sh example   install, compile the kernels (rigcal warm-up), solve the bundled
#                                 sample session, print the summary
#   bash scripts/dev.sh test      install, run linters (ruff, mypy) and the test suite
#   bash scripts/dev.sh lint      linters only
#
# Needs CPython 3.12 or 3.13 (mrcal ships wheels only for those): taken from
# $RIGCAL_PYTHON, else python3.13/python3.12 on PATH, else a pyenv-installed 3.12/3.13.
# uv is used from PATH, or installed into .cache/uv-bootstrap with pip if missing.
set -euo pipefail
cd "$(dirname "$0")/.."

job="${1:-}"
shift || true
case "$job" in
  example|test|lint) ;;
  *) echo "usage: bash scripts/dev.sh example|test|lint [extra pytest args]" >&2; exit 2 ;;
esac

say() { echo "[dev] $*" >&2; }

# A usable interpreter is one that runs and reports 3.12 or 3.13; print its real path.
probe() {
  "$@" -c 'import sys; assert sys.version_info[:2] in ((3, 12), (3, 13)); print(sys.executable)' 2>/dev/null
}

find_python() {
  local exe
  if [ -n "${RIGCAL_PYTHON:-}" ]; then
    probe "$RIGCAL_PYTHON" && return 0
    say "RIGCAL_PYTHON=$RIGCAL_PYTHON is not a working CPython 3.12/3.13"; return 1
  fi
  for cand in python3.13 python3.12; do
    if command -v "$cand" >/dev/null 2>&1 && exe=$(probe "$cand"); then echo "$exe"; return 0; fi
  done
  if command -v pyenv >/dev/null 2>&1; then
    for v in $(pyenv versions --bare 2>/dev/null | grep -E '^3\.1[23](\.[0-9]+)?$' | sort -rV); do
      local prefix
      prefix=$(pyenv prefix "$v" 2>/dev/null) || continue
      for cand in "$prefix/bin/python3.13" "$prefix/bin/python3.12"; do
        if [ -x "$cand" ] && exe=$(probe "$cand"); then echo "$exe"; return 0; fi
      done
    done
  fi
  say "no CPython 3.12 or 3.13 found (mrcal needs one); set RIGCAL_PYTHON=/path/to/python3.12"
  return 1
}

find_uv() {
  if command -v uv >/dev/null 2>&1; then command -v uv; return 0; fi
  local boot=.cache/uv-bootstrap
  if [ ! -x "$boot/bin/uv" ]; then
    say "uv not found; installing it into $boot"
    "$1" -m venv "$boot" >&2
    "$boot/bin/python" -m pip install --quiet uv >&2
  fi
  echo "$boot/bin/uv"
}

PY=$(find_python)
UV=$(find_uv "$PY")
export UV_PYTHON_DOWNLOADS=never
say "python: $PY"
say "uv: $("$UV" --version)"
"$UV" sync --frozen --python "$PY" --quiet >&2

run_lint() {
  say "ruff"
  .venv/bin/ruff check src tests benchmarks
  .venv/bin/ruff format --check --quiet src tests benchmarks
  say "mypy"
  .venv/bin/mypy
  say "lint-imports (the layer contract, docs/development.md)"
  local contract
  contract=$(.venv/bin/lint-imports --no-cache 2>&1) || { echo "$contract" >&2; return 1; }
  echo "$contract" | tail -n 1 >&2
}

case "$job" in
  example)
    out=out/example
    say "compiling rigcal's kernels once (rigcal warm-up; nothing to do when they are cached)"
    .venv/bin/rigcal warm-up
    .venv/bin/rigcal solve examples/box-session/picks.yaml -o "$out/rig.yaml" \
      --report "$out/report" --truth examples/box-session/truth.yaml --force
    say "rig file: $out/rig.yaml; report: $out/report/"
    ;;
  lint)
    run_lint
    ;;
  test)
    run_lint
    say "pytest"
    .venv/bin/pytest -m "not slow" --cov=rigcal --cov-report=term:skip-covered "$@"
    ;;
esac
