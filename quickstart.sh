#!/usr/bin/env bash
# evdense quick start: installs what it needs (idempotent), then runs the main job or the tests.
#   bash quickstart.sh run   [extra snakemake args]   # default config, results under results/
#   bash quickstart.sh test  [extra pytest args]      # the test suite
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3

need_apt=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so' || need_apt+=(libusb-1.0-0)   # open3d needs it
"$PY" -c 'import ensurepip, venv' 2>/dev/null || need_apt+=(python3-venv)
if [ ${#need_apt[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_apt[@]}" >/dev/null
  else
    echo "evdense needs the Debian packages: ${need_apt[*]} (run: sudo apt-get install ${need_apt[*]})" >&2
    exit 1
  fi
fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=.venv/.evdense-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "installing evdense and its dependencies into .venv (first run only) ..." >&2
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
  # torch first and pinned: anything else pulls a multi-GB CUDA build.
  .venv/bin/python -m pip install -q torch==2.13.0
  .venv/bin/python -m pip install -q -e ".[dev]"
  touch "$stamp"
fi

cmd=${1:-}
shift || true
case "$cmd" in
  run)  exec .venv/bin/snakemake --cores 2 --configfile config/config.yaml "$@" ;;
  test) exec .venv/bin/python -m pytest "$@" ;;
  *)    echo "usage: bash quickstart.sh run|test [args]" >&2; exit 2 ;;
esac
