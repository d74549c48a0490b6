#!/usr/bin/env bash
# test_install.sh (ctest cli_install) - the installed library, used the two
# ways docs/library.md shows, and the installed tools.
#
# Installs the build tree (HLOD_BUILD_DIR, already built) into a temporary
# prefix with `cmake --install`, then moves the prefix elsewhere (the CMake
# package, hlod.pc and the tools must not need the place they were
# installed to, nor the source or build tree), and checks:
#   - docs/library.md's "Using the library" shows tests/install/example/main.c;
#   - the headers, libraries, CMake package, hlod.pc, tools and camera
#     paths are there, and no installed package file names the source or
#     build tree or the first prefix;
#   - the installed hlod-gen-city and hlod-build make a tiny store;
#   - tests/install/example (docs/library.md's example, main.c, and link_all.c,
#     which takes a function of every library) builds with
#     find_package(hlod) and CMAKE_PREFIX_PATH, and with
#     `cc ... $(pkg-config --cflags --libs --static hlod)`; each example
#     renders a frame of the store with OSMesa that drew triangles covering
#     pixels, and each link_all runs;
#   - the installed hlod-bench and hlod-view name PREFIX/share/hlod in
#     --help (the build tree's name the source's data/), and hlod-bench runs
#     a built-in path by name, one that exists only under the prefix and
#     `walk` (data/paths/default).
# Exit status: non-zero if any check failed (the work folder is then kept).
set -u
SRC=${HLOD_SOURCE_DIR:?HLOD_SOURCE_DIR is not set}
BUILD=${HLOD_BUILD_DIR:?HLOD_BUILD_DIR is not set}
BIN=${HLOD_BIN_DIR:-$BUILD/bin}
CMAKE=${HLOD_CMAKE:-cmake}
CC=${HLOD_CC:-cc}
T=$(mktemp -d /tmp/hlod-test-install-XXXXXX)
. "$(dirname "$0")/../lib.sh" # pass, fail, ok()
finish() {
    echo "cli_install: $pass passed, $fail failed"
    if [ "$fail" -eq 0 ]; then
        rm -rf "$T"
        exit 0
    fi
    echo "work folder kept: $T"
    exit 1
}
# "nodes N triangles N pixels N" with both counts above zero
drew() { awk '$1 == "nodes" && $4 > 0 && $6 > 0 { f = 1 } END { exit !f }' "$1"; }

# ---- docs/library.md shows the example as it is ----
readme_code=$(awk '/^## Using the library/ { s = 1 } s && /^```c$/ { c = 1; next }
    c && /^```$/ { exit } c' "$SRC/docs/library.md")
main_code=$(sed -n '/^#include <hlod\/engine.h>/,$p' "$SRC/tests/install/example/main.c")
[ -n "$main_code" ] && [ "$readme_code" = "$main_code" ]
ok $? "docs/library.md's 'Using the library' shows tests/install/example/main.c"

# ---- install, then move the prefix ----
"$CMAKE" --install "$BUILD" --prefix "$T/first" >"$T/install.log" 2>&1
ok $? "cmake --install into a fresh prefix" || { cat "$T/install.log"; finish; }
mv "$T/first" "$T/prefix"
P=$T/prefix
PC=$(find "$P" -name hlod.pc -path '*/pkgconfig/*' | head -1)
LIBDIR=$(dirname "$(dirname "${PC:-/none/x}")")

# ---- what was installed ----
missing=""
for h in "$SRC"/include/hlod/*.h; do
    [ -f "$P/include/hlod/$(basename "$h")" ] || missing="$missing $h"
done
libs="core meshio preprocess engine osmesa"
[ -f "$BUILD/libhlod_egl.a" ] && libs="$libs egl"
for l in $libs; do
    [ -f "$LIBDIR/libhlod_$l.a" ] || missing="$missing libhlod_$l.a"
done
for f in hlodConfig.cmake hlodConfigVersion.cmake hlodTargets.cmake; do
    [ -f "$LIBDIR/cmake/hlod/$f" ] || missing="$missing $f"
done
[ -n "$PC" ] || missing="$missing hlod.pc"
for src in "$SRC"/preprocess/tools/hlod_*.c "$SRC"/engine/tools/hlod_*.c; do
    exe=$(basename "$src" .c)
    exe=${exe//_/-}
    if [ -x "$BIN/$exe" ] && [ ! -x "$P/bin/$exe" ]; then missing="$missing bin/$exe"; fi
done
for f in "$SRC"/data/paths/*/*.path; do
    rel=${f#"$SRC"/data/}
    cmp -s "$f" "$P/share/hlod/$rel" || missing="$missing share/hlod/$rel"
done
[ -z "$missing" ]
ok $? "installed: headers, libraries ($libs), CMake package, hlod.pc, tools, camera paths${missing:+ (missing:$missing)}"

named=$(grep -rlF -e "$SRC" -e "$BUILD" -e "$T/first" "$LIBDIR/cmake/hlod" "$PC" 2>/dev/null)
[ -z "$named" ]
ok $? "the CMake package and hlod.pc name no source, build or former prefix path${named:+ ($named)}"

# ---- a tiny store, by the installed tools ----
"$P/bin/hlod-gen-city" --preset tiny -o "$T/city.obj" --quiet &&
    "$P/bin/hlod-build" "$T/city.obj" -o "$T/city.hlod" --desired-tris 300 --quiet
ok $? "installed hlod-gen-city and hlod-build make a tiny store" || finish

# ---- find_package(hlod) ----
"$CMAKE" -S "$SRC/tests/install/example" -B "$T/cm" -DCMAKE_PREFIX_PATH="$P" \
    -DCMAKE_C_COMPILER="$CC" -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF >"$T/cm.log" 2>&1 &&
    grep -qxF "hlod_DIR:PATH=$LIBDIR/cmake/hlod" "$T/cm/CMakeCache.txt" &&
    "$CMAKE" --build "$T/cm" >>"$T/cm.log" 2>&1
ok $? "find_package(hlod) from the prefix: the example and link_all build" || tail -30 "$T/cm.log"
"$T/cm/hlod-example" "$T/city.hlod" >"$T/cm.out" 2>&1 && drew "$T/cm.out"
ok $? "find_package build renders a frame: $(cat "$T/cm.out" 2>/dev/null)"
"$T/cm/hlod-link-all" >/dev/null
ok $? "find_package build of link_all runs"

# ---- pkg-config --static ----
export PKG_CONFIG_PATH="$LIBDIR/pkgconfig"
cflags=$(pkg-config --cflags hlod) && libs_flags=$(pkg-config --cflags --libs --static hlod)
ok $? "pkg-config --static --libs hlod"
case "$cflags" in "-I$P/"*) true ;; *) false ;; esac
ok $? "pkg-config's include folder lies under the prefix ($cflags)"
egl_def=""
[ -f "$LIBDIR/libhlod_egl.a" ] && egl_def=-DHLOD_EXAMPLE_EGL
# shellcheck disable=SC2086
"$CC" -std=c11 -Wall -Wextra -Werror -o "$T/pc-example" "$SRC/tests/install/example/main.c" \
    $libs_flags >"$T/pc.log" 2>&1 &&
    "$CC" -std=c11 -Wall -Wextra -Werror $egl_def -o "$T/pc-link-all" \
        "$SRC/tests/install/example/link_all.c" $libs_flags >>"$T/pc.log" 2>&1
ok $? "cc \$(pkg-config --cflags --libs --static hlod): the example and link_all build" ||
    tail -30 "$T/pc.log"
"$T/pc-example" "$T/city.hlod" >"$T/pc.out" 2>&1 && drew "$T/pc.out"
ok $? "pkg-config build renders a frame: $(cat "$T/pc.out" 2>/dev/null)"
"$T/pc-link-all" >/dev/null
ok $? "pkg-config build of link_all runs"

# ---- the installed tools find their data under the prefix ----
want="$P/share/hlod/paths/default)"
for tool in hlod-bench hlod-view; do
    [ -x "$P/bin/$tool" ] || continue
    help=$("$P/bin/$tool" --help)
    line=$(echo "$help" | grep -A1 -- '--paths-dir' | tail -1)
    [ "$(echo $line)" = "$want" ] && ! echo "$help" | grep -qF -e "$SRC" -e "$BUILD"
    ok $? "installed $tool --help names the prefix's paths ($(echo $line))"
done
if [ -x "$BIN/hlod-bench" ]; then
    line=$("$BIN/hlod-bench" --help | grep -A1 -- '--paths-dir' | tail -1)
    [ "$(echo $line)" = "$SRC/data/paths/default)" ]
    ok $? "the build tree's hlod-bench names the source's data ($(echo $line))"
fi
probe=install-probe-$$
cp "$P/share/hlod/paths/default/walk.path" "$P/share/hlod/paths/default/$probe.path"
for name in "$probe" walk; do
    "$P/bin/hlod-bench" "$T/city.hlod" --path "$name" --out "$T/bench-$name" --width 160 \
        --height 96 --frames 5 --jitter-frames 0 --no-plots >"$T/bench-$name.log" 2>&1 &&
        grep -q '"frames": *5\b' "$T/bench-$name/summary.json"
    ok $? "installed hlod-bench --path $name (looked up under the prefix) runs 5 frames" ||
        tail -5 "$T/bench-$name.log"
done

finish
