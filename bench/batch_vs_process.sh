#!/usr/bin/env bash
# Batch throughput (issue 18): N volumes of SIZE³ through `sonomeshd batch` (one process, buffers
# and FFT plans reused) against N separate `sonomeshd process` runs, interleaved ROUNDS times.
# Usage: bench/batch_vs_process.sh [N=100] [SIZE=96] [ROUNDS=2]   (needs build/ with sonomeshd, probe-sim)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${SONOMESH_BUILD_DIR:-$root/build}"
n="${1:-100}" size="${2:-96}" rounds="${3:-2}"
work="$(mktemp -d /tmp/sonomesh-batch-bench.XXXXXX)"
trap 'rm -rf "$work"' EXIT
c=$(( size / 2 ))
# Five distinct phantoms (sphere, torus, cyst-needle at two seeds...), copied to N inputs.
kinds=(sphere torus cyst-needle ellipsoid sphere)
for k in 0 1 2 3 4; do
  "$build/sim/probe-sim" generate --phantom "${kinds[$k]}" --size "$size" --seed $((k + 1)) \
    --out "$work/src$k.nrrd" --truth "$work/truth$k.nrrd" >/dev/null
done
: > "$work/manifest.jsonl"
: > "$work/commands"
for k in 0 1 2 3 4; do
  seeds[$k]=$(python3 -c "import json;print(','.join(str(v) for v in json.load(open('$work/src$k.json'))['seed_index']))")
done
for i in $(seq 0 $((n - 1))); do
  cp "$work/src$((i % 5)).nrrd" "$work/v$i.nrrd"
  echo "{\"input\": \"v$i.nrrd\", \"seed_index\": [${seeds[$((i % 5))]}]}" >> "$work/manifest.jsonl"
  echo "$work/v$i.nrrd ${seeds[$((i % 5))]} $i" >> "$work/commands"
done
now() { date +%s.%N; }
for r in $(seq 1 "$rounds"); do
  rm -rf "$work/p" && mkdir -p "$work/p"
  t0=$(now)
  while read -r input seed i; do
    "$build/daemon/sonomeshd" process "$input" --seed-index "$seed" --mesh "$work/p/v$i.ply" \
      --report "$work/p/v$i.json" || true
  done < "$work/commands"
  t1=$(now)
  for jobs in 1 2; do
    rm -rf "$work/b"
    tb0=$(now)
    "$build/daemon/sonomeshd" batch --manifest "$work/manifest.jsonl" --out "$work/b" --jobs "$jobs" --quiet
    tb1=$(now)
    echo "round $r: $n x ${size}^3: process runs $(echo "$t1 - $t0" | bc) s, batch --jobs $jobs $(echo "$tb1 - $tb0" | bc) s"
  done
done
