#!/usr/bin/env bash
# Rebuild three.min.js (the report's vendored three.js) from the npm registry:
#   bash src/transcalib/report/vendor/build_three.sh [VERSION]
# Needs node and npm (at build time only: the report never loads anything at run time).
# Bundles the names exported by three-entry.js (three.js and its OrbitControls) into one
# minified classic script that defines the global THREE, with a header naming the
# version and the licence (LICENSE.three.txt, copied from the package).
set -euo pipefail
VERSION="${1:-0.187.0}"
ESBUILD=0.28.2
here="$(cd "$(dirname "$0")" && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cp "$here/three-entry.js" "$work/entry.js"
cd "$work"
npm init -y >/dev/null
npm install --no-audit --no-fund --silent "three@$VERSION" "esbuild@$ESBUILD"
npx esbuild entry.js --bundle --minify --format=iife --global-name=THREE --legal-comments=none \
  --log-level=warning --outfile=bundle.js
{
  printf '/* three.js %s (https://threejs.org), MIT licence: LICENSE.three.txt. The names of\n' "$VERSION"
  printf '   three-entry.js and OrbitControls, bundled by build_three.sh with esbuild %s. */\n' "$ESBUILD"
  cat bundle.js
} > "$here/three.min.js"
cp node_modules/three/LICENSE "$here/LICENSE.three.txt"
echo "wrote $here/three.min.js ($(wc -c < "$here/three.min.js") bytes), three $VERSION"
