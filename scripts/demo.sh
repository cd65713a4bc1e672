#!/usr/bin/env bash
# The README's demo command: installs what is missing, builds, and runs the daemon for a few
# seconds on the built-in probe simulator (a kidney cyst pierced by a biopsy needle).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/build.sh" --target sonomeshd probe-sim
build="${SONOMESH_BUILD_DIR:-$root/build}"
out="${1:-$root/out/demo}"
seconds="${DEMO_SECONDS:-5}"
rm -rf "$out"
mkdir -p "$out"
echo "demo: sonomeshd run --source sim:cyst-needle for ${seconds} s -> $out"
status=0
timeout --signal=INT --kill-after=10 "$seconds" \
  "$build/daemon/sonomeshd" run --source "sim:cyst-needle?rate=5&size=96" --out "$out" || status=$?
# timeout returns 124 when it had to send SIGINT, which is how the demo ends; anything else is real.
if [ "$status" -ne 0 ] && [ "$status" -ne 124 ]; then
  echo "demo: sonomeshd exited with $status" >&2
  exit "$status"
fi
echo
echo "journal: $out/journal.jsonl ($(wc -l < "$out/journal.jsonl") lines)"
echo "meshes:  $out/meshes/ ($(ls "$out/meshes" | wc -l) files), newest: $out/latest.ply"
tail -n 3 "$out/journal.jsonl"
