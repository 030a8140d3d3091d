#!/usr/bin/env bash
# Vendor three.js for the dashboard: fetch the package from the npm registry with `npm pack`
# (npm checks the tarball against the registry's integrity hash), copy the module files the
# dashboard imports and the licence under service/static/vendor/three/. No CDN is used at run time.
#
#   scripts/vendor_three.sh            # the pinned version
#   THREE_VERSION=0.187.0 scripts/vendor_three.sh
set -euo pipefail
cd "$(dirname "$0")/.."

VERSION="${THREE_VERSION:-0.187.0}"
DEST=service/static/vendor/three
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT

command -v npm >/dev/null || { echo "vendor_three: npm is needed (apt-get install -y npm)" >&2; exit 1; }
(cd "$TMP" && npm pack --silent "three@${VERSION}" >/dev/null)
tar -xzf "$TMP"/three-"${VERSION}".tgz -C "$TMP"
PKG="$TMP/package"

mkdir -p "$DEST"
rm -f "$DEST"/*.js
# three.module.js imports ./three.core.js; OrbitControls imports the bare name `three`,
# which the dashboard's import map (service/static/index.html) points at three.module.js.
cp "$PKG/build/three.module.js" "$PKG/build/three.core.js" "$DEST/"
cp "$PKG/examples/jsm/controls/OrbitControls.js" "$DEST/"
cp "$PKG/LICENSE" "$DEST/LICENSE"
echo "$VERSION" > "$DEST/VERSION"
echo "vendored three@${VERSION} into $DEST:"
ls -l "$DEST"
