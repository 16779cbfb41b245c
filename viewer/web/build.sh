#!/usr/bin/env bash
# Rebuilds dist/viewer.js (the page's only script, compiled into the viewer binary) from
# src/main.js and the pinned three.js, and dist/LICENSES.txt. Needs npm once; the output is
# committed, so `cargo build` and the page itself never need the network.
set -euo pipefail
cd "$(dirname "$0")"
npm ci --no-audit --no-fund
npx esbuild src/main.js --bundle --minify --format=iife --target=es2020 \
  --legal-comments=none --outfile=dist/viewer.js
{
  echo "The trainee page bundles the following npm packages (pinned in package-lock.json)."
  echo
  echo "three $(node -p "JSON.parse(require('fs').readFileSync('node_modules/three/package.json')).version") — MIT licence — https://threejs.org"
  echo "--------------------------------------------------------------------------------"
  cat node_modules/three/LICENSE
} > dist/LICENSES.txt
