#!/usr/bin/env bash
# test_docs.sh - the docs keep up with the tools (docs/testing.md):
#   - every flag a tool's --help prints (each --name token) is on the
#     tool's page docs/hlod-<verb>.md, in backticks;
#   - the check fails on a page with one flag's lines removed;
#   - every page under docs/ is linked from README.md, and every relative
#     link in README.md and docs/ names a file that exists;
#   - README.md is at most 200 lines.
# The settings table is kept equal to the engine's by test_settings.
# Env: HLOD_BIN_DIR (the tools), HLOD_SOURCE_DIR (the repository).
set -u
BIN=${HLOD_BIN_DIR:-build/bin}
SRC=${HLOD_SOURCE_DIR:-.}
. "$SRC/tests/lib.sh"
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT

# missing_flags TOOL PAGE: prints each flag of TOOL --help absent from PAGE.
missing_flags() {
    local tool=$1 page=$2 f
    "$BIN/$tool" --help 2>&1 | grep -o -- '--[a-z0-9][a-z0-9-]*' | sort -u >"$T/flags"
    [ -s "$T/flags" ] || { echo "(no flags in $tool --help)"; return; }
    while read -r f; do
        grep -q -- "\`$f\\b" "$page" || echo "$f"
    done <"$T/flags"
}

TOOLS="hlod-gen-city hlod-simplify hlod-build hlod-merge hlod-info hlod-export-3dtiles hlod-bench hlod-view hlod-lumigraph-bake hlod-lumigraph-serve"
[ -x "$BIN/hlod-bench-simplify" ] && TOOLS="$TOOLS hlod-bench-simplify"
[ -x "$BIN/hlod-bench-finish" ] && TOOLS="$TOOLS hlod-bench-finish"
for tool in $TOOLS; do
    page="$SRC/docs/$tool.md"
    if [ ! -x "$BIN/$tool" ] || [ ! -f "$page" ]; then
        ok 1 "$tool: the tool and docs/$tool.md are there"
        continue
    fi
    miss=$(missing_flags "$tool" "$page" | tr '\n' ' ')
    n=$("$BIN/$tool" --help 2>&1 | grep -o -- '--[a-z0-9][a-z0-9-]*' | sort -u | wc -l)
    [ -z "$miss" ]
    ok $? "$tool: its $n flags are on docs/$tool.md${miss:+ (missing: $miss)}"
done

# the check can fail: docs/hlod-info.md without the lines naming --verify
grep -v -- '`--verify' "$SRC/docs/hlod-info.md" >"$T/hlod-info.md"
miss=$(missing_flags hlod-info "$T/hlod-info.md")
[ "$miss" = "--verify" ]
ok $? "a page without --verify's lines is caught (missing: ${miss:-nothing})"

# every page linked from the README
unlinked=""
for page in "$SRC"/docs/*.md; do
    name=${page##*/}
    grep -q "](docs/$name)" "$SRC/README.md" || unlinked="$unlinked $name"
done
[ -z "$unlinked" ]
ok $? "every docs page is linked from README.md${unlinked:+ (not:$unlinked)}"

# every relative link names a file (anchors and URLs aside)
broken=""
for f in "$SRC/README.md" "$SRC"/docs/*.md; do
    dir=$(dirname "$f")
    for l in $(grep -o '](\([^)#: ]*\)' "$f" | sed 's/^](//'); do
        [ -z "$l" ] && continue
        [ -e "$dir/$l" ] || broken="$broken ${f#$SRC/}:$l"
    done
done
[ -z "$broken" ]
ok $? "every relative link in README.md and docs/ names a file${broken:+ (broken:$broken)}"

lines=$(wc -l <"$SRC/README.md")
[ "$lines" -le 200 ]
ok $? "README.md is $lines lines (at most 200)"

echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
