#!/bin/sh
# fetch-meshes.sh - put real test meshes into data/meshes/ (gitignored).
#
# The meshes come from two Debian packages: libcgal-demo ships CGAL's mesh
# collection (bunny, fandisk, shark, elephant as OFF) and assimp-testmodels
# ships assimp's test models (a textured OBJ, glTF 2.0 text and binary, PLY).
# The .deb files are kept in data/cache/ so a second run needs no network;
# a run that finds every mesh in place does nothing.
set -eu

root=$(cd "$(dirname "$0")/.." && pwd)
meshes="$root/data/meshes"
cache="$root/data/cache"

CGAL_FILES="bunny00.off fandisk.off mech-holes-shark.off elephant.off"
ASSIMP_OBJ="spider.obj spider.mtl SpiderTex.jpg wal67ar_small.jpg wal69ar_small.jpg drkwood2.jpg engineflare1.jpg"
ASSIMP_GLTF="BoxTextured.gltf BoxTextured0.bin CesiumLogoFlat.png"
ASSIMP_GLB="BoxTextured.glb 2CylinderEngine.glb"
ASSIMP_PLY="cube_binary.ply cube_uv.ply Wuson.ply"
ALL="$CGAL_FILES $ASSIMP_OBJ $ASSIMP_GLTF $ASSIMP_GLB $ASSIMP_PLY"

missing=""
for f in $ALL; do
    [ -s "$meshes/$f" ] || missing="$missing $f"
done
if [ -z "$missing" ]; then
    echo "fetch-meshes: all meshes already in data/meshes/"
    exit 0
fi

mkdir -p "$meshes" "$cache"

# Downloads one package's .deb into data/cache/ unless it is already there;
# refreshes the package lists only when a plain download fails.
fetch_deb() {
    pkg=$1
    for d in "$cache/${pkg}_"*.deb; do
        [ -f "$d" ] && return 0
    done
    if ! (cd "$cache" && apt-get download "$pkg" >/dev/null 2>&1); then
        echo "fetch-meshes: apt-get download $pkg failed, running apt-get update"
        apt-get update >/dev/null
        (cd "$cache" && apt-get download "$pkg")
    fi
    # apt-get download runs as _apt when it can, which may leave a partial
    # file behind on failure; a .deb that dpkg-deb cannot read is refetched
    # next run.
    for d in "$cache/${pkg}_"*.deb; do
        dpkg-deb --info "$d" >/dev/null 2>&1 || { rm -f "$d"; echo "fetch-meshes: bad $d" >&2; exit 1; }
    done
}

fetch_deb libcgal-demo
fetch_deb assimp-testmodels

# Path of the (single) cached .deb of a package.
deb_of() {
    for d in "$cache/${1}_"*.deb; do
        echo "$d"
        return 0
    done
}

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT INT TERM

dpkg-deb -x "$(deb_of libcgal-demo)" "$tmp/cgal"
mkdir -p "$tmp/cgal-data"
set --
for f in $CGAL_FILES; do
    set -- "$@" "data/meshes/$f"
done
tar -xzf "$tmp/cgal/usr/share/doc/libcgal-dev/data.tar.gz" -C "$tmp/cgal-data" "$@"

dpkg-deb -x "$(deb_of assimp-testmodels)" "$tmp/assimp"
models="$tmp/assimp/usr/share/assimp/models"

# Copies src to data/meshes/NAME through a temporary name so an interrupted
# run never leaves a truncated mesh that the next run would take as done.
put() {
    src=$1
    name=$2
    cp "$src" "$meshes/.$name.part"
    mv "$meshes/.$name.part" "$meshes/$name"
    echo "fetch-meshes: $name ($(wc -c <"$meshes/$name") bytes)"
}

for f in $CGAL_FILES; do
    put "$tmp/cgal-data/data/meshes/$f" "$f"
done
for f in spider.obj spider.mtl; do
    put "$models/OBJ/$f" "$f"
done
# spider.mtl names its textures as ".\NAME.jpg": copy every file it references.
for tex in $(sed -n 's/^[[:space:]]*map_Kd[[:space:]]*//p' "$models/OBJ/spider.mtl" | tr -d '\r' | sed 's/^\.\\//'); do
    put "$models/OBJ/$tex" "$tex"
done
for f in $ASSIMP_GLTF; do
    put "$models/glTF2/BoxTextured-glTF/$f" "$f"
done
put "$models/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb" BoxTextured.glb
put "$models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb" 2CylinderEngine.glb
for f in $ASSIMP_PLY; do
    put "$models/PLY/$f" "$f"
done

for f in $ALL; do
    [ -s "$meshes/$f" ] || { echo "fetch-meshes: $f is missing after the fetch" >&2; exit 1; }
done
echo "fetch-meshes: done, meshes in $meshes"
