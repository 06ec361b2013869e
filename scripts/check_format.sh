#!/usr/bin/env bash
# Checks that every C++ source under src include apps test tools is formatted by clang-format 14 with
# the repository's .clang-format; lists the files that are not and fails. --fix reformats them in place.
# Generated files are left alone (src/tracking/brief_pattern.inc: tools/learn_brief_pattern.cpp
# writes it, and the tool must regenerate it byte for byte).
# Usage: scripts/check_format.sh [--fix] [FILE...]   (default: every tracked source file)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

fix=0
files=()
for a in "$@"; do
  case "$a" in
    --fix) fix=1 ;;
    -h|--help) sed -n '2,6p' "$0"; exit 0 ;;
    -*) echo "check_format.sh: unknown option '$a' (valid: --fix)" >&2; exit 2 ;;
    *) files+=("$a") ;;
  esac
done

# Another major version formats some constructs differently: insist on the one CI uses.
cf=
for c in clang-format-14 clang-format; do
  if command -v "$c" >/dev/null 2>&1 && "$c" --version | grep -q 'version 14\.'; then
    cf=$c
    break
  fi
done
if [ -z "$cf" ]; then
  echo "check_format.sh: clang-format 14 not found (Debian 12: apt-get install clang-format;" \
    "scripts/install_deps.sh installs it)" >&2
  exit 2
fi

if [ "${#files[@]}" -eq 0 ]; then
  mapfile -t files < <(git ls-files -- src include apps test tools |
    grep -E '\.(h|hpp|c|cc|cpp)$' || true)
fi

if [ "$fix" = 1 ]; then
  "$cf" -i --style=file "${files[@]}"
  echo "check_format.sh: formatted ${#files[@]} file(s) with $("$cf" --version | sed 's/.*version //')."
  exit 0
fi

# One clang-format process for all files: each difference is reported as "FILE:LINE:COL: error: ...".
rc=0
out=$("$cf" --style=file --dry-run -Werror "${files[@]}" 2>&1 >/dev/null) || rc=$?
mapfile -t bad < <(sed -n 's/^\(.*\):[0-9]*:[0-9]*: error: .*/\1/p' <<<"$out" | sort -u)
if [ "$rc" -ne 0 ] && [ "${#bad[@]}" -eq 0 ]; then
  echo "check_format.sh: $cf failed:" >&2
  echo "$out" >&2
  exit 2
fi
if [ "${#bad[@]}" -ne 0 ]; then
  echo "check_format.sh: ${#bad[@]} of ${#files[@]} file(s) are not formatted (.clang-format, $cf):"
  printf '  %s\n' "${bad[@]}"
  echo "Fix them with: bash scripts/check_format.sh --fix ${bad[*]}"
  exit 1
fi
echo "check_format.sh: all ${#files[@]} file(s) formatted."
