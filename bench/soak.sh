#!/usr/bin/env bash
# Soak (not CI): streams COUNT 64³ volumes with faults (corrupt payloads, dropped and truncated
# records, disconnects) from probe-sim through `sonomeshd run`, samples the daemon's RSS, and
# checks that every sequence 0..COUNT-1 has exactly one journal line.
#   bench/soak.sh [COUNT=10000] [RATE_HZ=50]      (binaries from SONOMESH_BUILD_DIR or ./build)
# Prints RSS after warm-up (1 % of the lines written) and at the end; fails if the end is more
# than 10 % above the start or any sequence is missing or doubled.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${SONOMESH_BUILD_DIR:-$root/build}"
count="${1:-10000}" rate="${2:-50}"
work="$(mktemp -d /tmp/sonomesh-soak.XXXXXX)"
sock="$work/probe.sock" out="$work/out"
echo "soak: $count volumes at $rate Hz, work dir $work"

"$build/sim/probe-sim" serve --phantom sphere --size 64 --rate "$rate" --count "$count" \
  --corrupt-every 97 --drop-every 89 --truncate-every 251 --disconnect-every 1009 \
  --down-ms 200 --listen "unix:$sock" 2>"$work/probe.err" &
probe=$!
for _ in $(seq 100); do [ -S "$sock" ] && break; sleep 0.1; done
"$build/daemon/sonomeshd" run --source "unix:$sock" --out "$out" --http off --keep-meshes 20 \
  2>"$work/daemon.err" &
daemon=$!

rss_kb() { awk '/^VmRSS:/ {print $2}' "/proc/$1/status" 2>/dev/null || echo 0; }
lines() { [ -f "$out/journal.jsonl" ] && wc -l <"$out/journal.jsonl" || echo 0; }
rss_start=0 rss_end=0 rss_max=0 start_s=$(date +%s)
while kill -0 "$daemon" 2>/dev/null; do
  r=$(rss_kb "$daemon")
  [ "${r:-0}" -gt 0 ] || break
  rss_end=$r
  [ "$r" -gt "$rss_max" ] && rss_max=$r
  if [ "$rss_start" -eq 0 ] && [ "$(lines)" -ge $(( count / 100 )) ]; then rss_start=$r; fi
  sleep 1
done
wait "$daemon" && code=0 || code=$?
wait "$probe" || true
elapsed=$(( $(date +%s) - start_s ))

seqs="$work/sequences"
grep -o '"sequence":[0-9][0-9]*' "$out/journal.jsonl" | cut -d: -f2 | sort -n >"$seqs"
distinct=$(uniq <"$seqs" | wc -l)
doubled=$(uniq -d <"$seqs" | wc -l)
first=$(head -1 "$seqs") last=$(tail -1 "$seqs")
echo "soak: daemon exit $code after $elapsed s; journal $(lines) lines, $distinct sequences" \
     "($first..$last), $doubled doubled, $(grep -c '"sequence":null' "$out/journal.jsonl" || true)" \
     "rejected without a sequence"
for s in processed skipped failed rejected lost; do
  printf 'soak:   %-9s %s\n' "$s" "$(grep -c "\"status\":\"$s\"" "$out/journal.jsonl" || true)"
done
echo "soak: RSS after warm-up ${rss_start} kB, at the end ${rss_end} kB, max ${rss_max} kB"
ok=1
[ "$code" -eq 0 ] || { echo "soak: FAIL daemon exit $code"; ok=0; }
[ "$distinct" -eq "$count" ] && [ "$first" -eq 0 ] && [ "$last" -eq $(( count - 1 )) ] ||
  { echo "soak: FAIL not every sequence 0..$(( count - 1 )) has a line"; ok=0; }
[ "$doubled" -eq 0 ] || { echo "soak: FAIL $doubled sequences have two lines"; ok=0; }
[ "$rss_end" -le $(( rss_start * 110 / 100 )) ] ||
  { echo "soak: FAIL RSS grew more than 10 %"; ok=0; }
[ "$ok" -eq 1 ] && { echo "soak: OK"; rm -rf "$work"; exit 0; }
echo "soak: kept $work for inspection"; exit 1
