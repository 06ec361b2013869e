#!/usr/bin/env bash
# Checks that every repository path the documentation mentions exists, so that a renamed or removed
# file cannot leave the README pointing at nothing. A path is a word starting with one of the
# repository's top-level folders (src/ include/ apps/ config/ docs/ scripts/ test/ tools/ third_party/
# msg/ cmake/ .ci/) or naming a top-level file (CMakeLists.txt, package.xml, .clang-format,
# .clang-tidy, any top-level *.md), in text, code blocks and links alike; a markdown link's target is
# taken relative to the document (docs/ros.md's [..](reliability.md) is docs/reliability.md), and
# so is a bare NAME.md. `*` must match at least one file, each of `{a,b}` must exist, and `<name>`
# stands for any one path component. Paths of outputs (out/, build/, OUT/) and of the shared data
# (../shared/data) are not the repository's and are not checked.
# Usage: scripts/check_docs.sh [FILE.md...]   (default: README.md docs/*.md third_party/README.md)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
if [ $# -eq 0 ]; then set -- README.md docs/*.md third_party/README.md; fi
exec /usr/bin/python3 - "$@" <<'PY'
import glob, os, re, sys

TOP = r"(?:src|include|apps|config|docs|scripts|test|tools|third_party|msg|cmake|\.ci)"
FILES = r"(?:CMakeLists\.txt|package\.xml|\.clang-format|\.clang-tidy|[A-Za-z_-]+\.md)"
# Not preceded by a path character (so out/room/src/... or ../shared/data/docs are not taken), then
# a top-level folder and the rest of the path, or a top-level file on its own.
PATH = re.compile(r"(?<![\w./~$:-])(" + TOP + r"/[\w./*{},<>+-]*|" + FILES + r")(?![\w/])")


def expand_braces(p):
    m = re.search(r"\{([^{}]*)\}", p)
    if not m:
        return [p]
    return [q for alt in m.group(1).split(",") for q in expand_braces(p[: m.start()] + alt + p[m.end():])]


LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")


def exists(p, doc_dir):
    p = re.sub(r"<[^<>/]*>", "*", p)
    return all(
        glob.glob(q) or ("/" not in q.rstrip("/") and glob.glob(os.path.join(doc_dir, q))) for q in expand_braces(p)
    )


bad = 0
checked = 0
for doc in sys.argv[1:]:
    with open(doc, encoding="utf-8") as f:
        doc_dir = os.path.dirname(doc)
        for lineno, line in enumerate(f, 1):
            paths = [m.group(1).rstrip(".,:;)") for m in PATH.finditer(line)]
            for m in LINK.finditer(line):
                t = m.group(1)
                if not re.match(r"[a-z]+:", t):  # not http:, mailto:, ...
                    paths.append(os.path.normpath(os.path.join(doc_dir, t)))
            for p in dict.fromkeys(paths):  # each path once per line, in order
                if "{" in p and "}" not in p:  # a brace list cut by the regex: take its stem
                    p = p[: p.index("{")]
                checked += 1
                if not exists(p, doc_dir):
                    print(f"{doc}:{lineno}: '{p}' does not exist in the repository")
                    bad += 1
if bad:
    print(f"check_docs.sh: {bad} of {checked} path(s) mentioned in {' '.join(sys.argv[1:])} do not exist")
    sys.exit(1)
print(f"check_docs.sh: all {checked} path(s) mentioned in {len(sys.argv) - 1} file(s) exist")
PY
