#!/usr/bin/env bash
# Long fuzz runs (not CI): every libFuzzer target for RUNS executions (default 10⁶) or SECONDS,
# whichever ends first, nice'd, one after the other; prints libFuzzer's final stats per target.
#   scripts/fuzz_long.sh [RUNS=1000000] [SECONDS=3600] [TARGET...]
# Needs the sanitizer build (SONOMESH_FUZZ=1 ./scripts/test.sh builds it; SONOMESH_BUILD_DIR,
# default build-asan). Corpora grow in BUILD/fuzz/work/<target>/corpus, findings land in
# BUILD/fuzz/work/<target>/artifacts.
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${SONOMESH_BUILD_DIR:-$root/build-asan}"
runs="${1:-1000000}" seconds="${2:-3600}"
shift $(( $# > 2 ? 2 : $# ))
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(fuzz_probe_stream fuzz_igtl fuzz_nrrd fuzz_metaimage fuzz_nifti fuzz_ply
                                     fuzz_run_config fuzz_seed_body)
status=0
for t in "${targets[@]}"; do
  exe="$build/fuzz/$t"
  [ -x "$exe" ] || { echo "fuzz_long: $exe not built" >&2; status=1; continue; }
  log="$build/fuzz/work/$t.long.log"
  mkdir -p "$build/fuzz/work"
  nice -n 19 "$root/fuzz/run_fuzz.sh" "$exe" "$root/fuzz/corpus/$t" "$build/fuzz/work/$t" \
    "$seconds" -runs="$runs" >"$log" 2>&1
  rc=$?
  execs=$(grep -o 'stat::number_of_executed_units: [0-9]*' "$log" | awk '{print $2}')
  rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | awk '{print $2}')
  last=$(grep -E '^#[0-9]+' "$log" | tail -1)  # libFuzzer's last status line: cov, ft, corp
  cov=$(grep -o 'cov: [0-9]*' <<<"$last" | awk '{print $2}')
  ft=$(grep -o 'ft: [0-9]*' <<<"$last" | awk '{print $2}')
  corp=$(grep -o 'corp: [0-9]*/[0-9]*[a-zA-Z]*' <<<"$last" | awk '{print $2}')
  found=$(find "$build/fuzz/work/$t/artifacts" -type f | wc -l)
  echo "fuzz_long: $t exit $rc, ${execs:-?} executions, ${rate:-?} exec/s, cov ${cov:-?}," \
       "ft ${ft:-?}, corpus ${corp:-?}, ${found} artifacts, log $log"
  [ "$rc" -eq 0 ] || status=1
done
exit $status
