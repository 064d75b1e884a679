#!/usr/bin/env bash
# Install the project with its test extra at the tested versions (constraints.txt), the Debian packages some tests need
# (where we are root): chromium for the console's browser tests, docker-compose to
# validate docker/compose.yaml (it only parses the file; no Docker engine runs).
# Then run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install -q -c constraints.txt -e '.[test]'
missing=()
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
command -v docker-compose >/dev/null 2>&1 || docker compose version >/dev/null 2>&1 || missing+=(docker-compose)
if [ "$(id -u)" = "0" ] && [ ${#missing[@]} -gt 0 ]; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null) \
    || echo "note: could not install ${missing[*]}; the tests that need them will skip and say why" >&2
fi
# Two test processes (the machine's two cores; most tests wait on servers, browsers and robots): each file runs
# whole in one process, and the files that start Ray run one after another (tests/conftest.py).
exec python -m pytest -n 2 --dist loadgroup "$@"
