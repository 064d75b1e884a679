#!/usr/bin/env bash
# Install the project with its test extra, the Debian packages the browser tests
# need (where we are root), and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install -q -e '.[test]'
if [ "$(id -u)" = "0" ] && ! command -v chromium >/dev/null 2>&1; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
    || echo "note: could not install chromium; the browser tests will skip and say why" >&2
fi
exec python -m pytest "$@"
