#!/usr/bin/env bash
# The map is built with Vite 7, which needs Node.js 20.19 or newer (Debian 12's own nodejs
# is 18: too old). Say so plainly instead of failing deep inside npm.
set -euo pipefail
if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
  echo "Node.js 20.19+ with npm is needed to build the map (frontend/); install it first." >&2
  exit 1
fi
version=$(node --version | sed 's/^v//')
major=${version%%.*}
minor=$(echo "$version" | cut -d. -f2)
if [ "$major" -lt 20 ] || { [ "$major" -eq 20 ] && [ "$minor" -lt 19 ]; }; then
  echo "Node.js $version is too old to build the map: 20.19 or newer is needed." >&2
  exit 1
fi
