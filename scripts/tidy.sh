#!/usr/bin/env bash
# Runs clang-tidy (the repository's .clang-tidy) on the C++ files changed against a base ref: the
# files a branch touches, committed or not. A changed header is checked through its own source file
# (include/nerfslam/M/X.h -> src/M/X.cpp) when there is one; findings are reported in the changed
# files only, not in the unchanged headers they include. Compile flags come from
# BUILD/compile_commands.json (written by every CMake configure of this project); files the build
# does not compile (e.g. apps/ros without ROS) are skipped with a note. Fails when clang-tidy reports
# anything in those files.
# Usage: scripts/tidy.sh [--base REF] [--build DIR] [--fix] [--list] [FILE...]
#   --base REF   compare against REF (default: origin/main if it exists, else main)
#   --build DIR  build directory with compile_commands.json (default: build)
#   --fix        apply clang-tidy's fixes in place (then re-run scripts/check_format.sh)
#   --list       print the files that would be checked, and stop
#   FILE...      check these files instead of the changed ones
#   TIDY_JOBS=N  files checked in parallel (default 1; the shared machine: at most 2)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

base=
build=build
fix=()
list=0
files=()
while [ $# -gt 0 ]; do
  case "$1" in
    --base) base=${2:?--base needs a ref}; shift ;;
    --build) build=${2:?--build needs a directory}; shift ;;
    --fix) fix=(--fix) ;;
    --list) list=1 ;;
    -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
    -*) echo "tidy.sh: unknown option '$1' (valid: --base REF, --build DIR, --fix, --list)" >&2; exit 2 ;;
    *) files+=("$1") ;;
  esac
  shift
done

tidy=
for c in clang-tidy-14 clang-tidy; do
  command -v "$c" >/dev/null 2>&1 && { tidy=$c; break; }
done
if [ -z "$tidy" ]; then
  echo "tidy.sh: clang-tidy not found (Debian 12: apt-get install clang-tidy; scripts/install_deps.sh installs it)" >&2
  exit 2
fi
db=$build/compile_commands.json
if [ ! -f "$db" ]; then
  echo "tidy.sh: $db not found: configure the build first (bash scripts/build.sh, or cmake -S . -B $build)" >&2
  exit 2
fi

if [ "${#files[@]}" -eq 0 ]; then
  if [ -z "$base" ]; then
    if git rev-parse -q --verify origin/main >/dev/null; then base=origin/main; else base=main; fi
  fi
  mb=$(git merge-base "$base" HEAD) || { echo "tidy.sh: no merge base between '$base' and HEAD" >&2; exit 2; }
  # Against the merge base, so that what landed on the base since is not ours; the working tree
  # is included (uncommitted changes count).
  mapfile -t files < <(git diff --name-only --diff-filter=d "$mb" -- src include apps test tools |
    grep -E '\.(h|hpp|cc|cpp)$' || true)
  echo "tidy.sh: ${#files[@]} C++ file(s) changed against $base ($(git rev-parse --short "$mb"))"
fi
# Sources are checked themselves, headers through their own source file; findings are reported in
# those files only (--header-filter: exactly the headers named), not in every header they include.
sources=()
headers=()
for f in "${files[@]}"; do
  case "$f" in
    include/nerfslam/*.h)
      headers+=("$f")
      src=${f#include/nerfslam/}
      src=src/${src%.h}.cpp
      if [ -f "$src" ]; then sources+=("$src"); else echo "tidy.sh: $f has no source of its own:" \
        "checked only through the changed sources that include it"; fi ;;
    *.h | *.hpp)
      headers+=("$f")
      stem=${f%.*}
      own=0
      for e in cpp cc; do [ -f "$stem.$e" ] && { sources+=("$stem.$e"); own=1; }; done
      [ "$own" = 1 ] || echo "tidy.sh: $f has no source of its own: checked only through the changed" \
        "sources that include it" ;;
    *) sources+=("$f") ;;
  esac
done
mapfile -t files < <(printf '%s\n' "${sources[@]}" | sed '/^$/d' | sort -u)
header_filter='^$'
if [ "${#headers[@]}" -gt 0 ]; then
  header_filter="^($(printf '%s\n' "${headers[@]}" | sed "s|^|$root/|; s|[.+]|\\\\&|g" | paste -sd'|'))\$"
fi

# Only what the build compiles has flags.
compiled=()
for f in "${files[@]}"; do
  if grep -q "\"file\": \"$root/$f\"" "$db"; then
    compiled+=("$f")
  else
    echo "tidy.sh: skipping $f (not in $db)"
  fi
done
if [ "${#compiled[@]}" -eq 0 ]; then
  echo "tidy.sh: nothing to check."
  exit 0
fi
if [ "$list" = 1 ]; then
  printf '%s\n' "${compiled[@]}"
  [ "${#headers[@]}" -eq 0 ] || printf 'findings also in: %s\n' "${headers[@]}"
  exit 0
fi

jobs=${TIDY_JOBS:-1}
echo "tidy.sh: $tidy on ${#compiled[@]} file(s), $jobs at a time"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
printf '%s\n' "${compiled[@]}" |
  xargs -P "$jobs" -I{} "$tidy" -p "$build" --quiet --header-filter="$header_filter" "${fix[@]}" {} 2>/dev/null |
  tee "$log" || true
# A header's finding is reported by every file that includes it: count each once.
findings=$(grep -E '^[^ ]+:[0-9]+:[0-9]+: (warning|error):' "$log" | sort -u || true)
if [ -n "$findings" ]; then
  echo "tidy.sh: $(wc -l <<<"$findings") finding(s) checking ${#compiled[@]} file(s):"
  grep -oE '\[[a-z0-9.,-]+\]$' <<<"$findings" | sort | uniq -c | sort -rn
  exit 1
fi
echo "tidy.sh: no findings in ${#compiled[@]} file(s)."
