#!/usr/bin/env bash
# Fails (exit 1, the files named) when a C++ file under the given folders is not formatted by the
# repo's .clang-format with clang-format-14. Run by the CTest test `format`.
#   scripts/check_format.sh [CLANG_FORMAT] [FOLDER ...]   (default: clang-format-14, every C++ folder)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
tool="${1:-clang-format-14}"
shift || true
folders=("$@")
[ ${#folders[@]} -gt 0 ] || folders=(acquire volume mesh segment reconstruct daemon sim tests bench fuzz)
cd "$root"
bad=0
while IFS= read -r -d '' file; do
  if ! "$tool" --style=file --dry-run --Werror "$file" >/dev/null 2>&1; then
    echo "not formatted: $file (run: $tool -i --style=file $file)"
    bad=1
  fi
done < <(find "${folders[@]}" \( -name '*.cpp' -o -name '*.h' \) -print0 | sort -z)
exit $bad
