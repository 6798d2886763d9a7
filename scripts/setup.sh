#!/usr/bin/env bash
# Set up everything the project needs on a fresh Debian machine:
#  1. a libLLVM that Dr.Jit's CPU backend can use (Debian 12's LLVM 15 crashes Dr.Jit 1.5;
#     libllvm19 works), installed with apt-get when none >= 16 is present;
#  2. a virtual environment in .venv/ with the project installed (editable) and its test extras;
#  3. with --test (`make test`): headless Chromium and its driver from Debian, with which the
#     test suite checks report.html in a real browser.
# Idempotent: a second run only re-installs when pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."
WITH_TEST_TOOLS=0
[ "${1:-}" = "--test" ] && WITH_TEST_TOOLS=1

have_llvm() {
  for d in /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/lib64 /usr/lib /usr/local/lib; do
    for v in 21 20 19 18 17 16; do
      if ls "$d"/libLLVM-"$v"*.so* >/dev/null 2>&1 || ls "$d"/libLLVM.so."$v"* >/dev/null 2>&1; then
        return 0
      fi
    done
  done
  return 1
}

if ! have_llvm; then
  echo "setup: no libLLVM >= 16 found; installing Debian's libllvm19 (Dr.Jit CPU backend)"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  if ! "$PYTHON" -m venv .venv 2>/dev/null; then
    echo "setup: python3 -m venv failed; installing python3-venv"
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-venv >/dev/null
    rm -rf .venv
    "$PYTHON" -m venv .venv
  fi
fi

stamp=.venv/.rfidstudy-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ constraints.txt -nt "$stamp" ]; then
  .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip
  # constraints.txt pins the ray tracer to the versions the project was tested with
  .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e ".[test]"
  touch "$stamp"
fi
if [ "$WITH_TEST_TOOLS" -eq 1 ] && { ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; }; then
  echo "setup: installing Debian's chromium and chromium-driver (the report's browser test)"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  # without apt (no sudo, no network) the tests still run: the browser test then fails
  # naming what is missing, the rest of the suite is unaffected
  if ! { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install \
      -y -qq --no-install-recommends chromium chromium-driver >/dev/null; }; then
    echo "setup: WARNING: could not install chromium and chromium-driver; the report's" \
      "browser test will fail until they are installed" >&2
  fi
fi
echo "setup: ready (.venv)"
