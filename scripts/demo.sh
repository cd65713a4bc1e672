#!/usr/bin/env bash
# The README's demo command: installs what is missing, builds, and runs the daemon on the
# built-in probe simulator (a kidney cyst pierced by a biopsy needle) with the live page on
# http://127.0.0.1:8787/ (DEMO_HTTP overrides). For a few seconds by default; with --watch until
# Ctrl-C, so the page can be opened and the cyst watched breathing.
#   ./scripts/demo.sh [--watch] [OUT]
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
watch=0
if [ "${1:-}" = "--watch" ]; then
  watch=1
  shift
fi
"$root/scripts/build.sh" --target sonomeshd probe-sim
build="${SONOMESH_BUILD_DIR:-$root/build}"
out="${1:-$root/out/demo}"
seconds="${DEMO_SECONDS:-5}"
http="${DEMO_HTTP:-127.0.0.1:8787}"
rm -rf "$out"
mkdir -p "$out"
cmd=("$build/daemon/sonomeshd" run --source "sim:cyst-needle?rate=5&size=96" --out "$out"
     --http "$http")
status=0
if [ "$watch" -eq 1 ]; then
  echo "demo: sonomeshd run --source sim:cyst-needle -> $out"
  echo "demo: open http://$http/ in a browser; Ctrl-C stops the daemon"
  # The daemon takes SIGINT itself (finishes the volume in hand, exits 0).
  "${cmd[@]}" || status=$?
else
  echo "demo: sonomeshd run --source sim:cyst-needle for ${seconds} s -> $out"
  echo "demo: the live page is at http://$http/ while it runs (./scripts/demo.sh --watch keeps it)"
  timeout --signal=INT --kill-after=10 "$seconds" "${cmd[@]}" || status=$?
  # timeout returns 124 when it had to send SIGINT, which is how the demo ends.
  if [ "$status" -eq 124 ]; then status=0; fi
fi
if [ "$status" -ne 0 ] && [ "$status" -ne 130 ]; then
  echo "demo: sonomeshd exited with $status" >&2
  exit "$status"
fi
echo
echo "journal: $out/journal.jsonl ($(wc -l < "$out/journal.jsonl") lines)"
echo "meshes:  $out/meshes/ ($(ls "$out/meshes" | wc -l) files), newest: $out/latest.ply"
tail -n 3 "$out/journal.jsonl"
