#!/usr/bin/env bash
# One fuzz smoke run: run_fuzz.sh FUZZER SEED_DIR WORK_DIR SECONDS [libFuzzer flags...]
# Runs FUZZER for SECONDS on the committed seeds plus the inputs it found before (WORK_DIR, which
# also receives new inputs and any crash artifact). Exit non-zero on a finding, like libFuzzer.
set -euo pipefail
fuzzer="$1" seeds="$2" work="$3" seconds="$4"
shift 4
mkdir -p "$work/corpus" "$work/artifacts"
# detect_leaks stays on: a leak on a bad input is a finding (a daemon reads many files).
# The readers take paths: their files go to memory, not to a disk shared with the builds.
[ -d /dev/shm ] && export TMPDIR="${TMPDIR:-/dev/shm}"
export ASAN_OPTIONS="${ASAN_OPTIONS:-abort_on_error=1:detect_leaks=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
# SONOMESH_FUZZ_CORPUS_ONLY=1 runs every committed seed and regression input once, without
# mutating: a deterministic gate (CI), where a mutational run's finding would depend on luck.
budget=(-max_total_time="$seconds")
[ "${SONOMESH_FUZZ_CORPUS_ONLY:-0}" = 1 ] && budget=(-runs=0)
exec "$fuzzer" "${budget[@]}" -timeout=20 -rss_limit_mb=2048 -max_len=65536 \
  -print_final_stats=1 -artifact_prefix="$work/artifacts/" "$@" "$work/corpus" "$seeds"
