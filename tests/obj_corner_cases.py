#!/usr/bin/env python3
"""obj_corner_cases.py OUT_DIR - writes OUT_DIR/corners.obj (+ .mtl): an OBJ
file with what the OBJ reader handles beyond the generated city, for the
sharded build's identity check (tests/test_shard.sh): a shard streams the
file one object at a time (hlod_obj_stream), the single build reads it
whole, and the two must give the same blocks.

What it holds:
  - faces before any o/g line and before any usemtl (an object named after
    the file, with the "default" material);
  - usemtl before the mtllib line that defines it; a material no library
    defines; a texture (map_Kd) copied from the first PNG given;
  - o and g lines, an object with no faces;
  - faces as v, v/vt, v//vn and v/vt/vn, mixed in one file; quads and
    pentagons (fan-triangulated); negative (relative) indices;
  - an object whose faces use vertices defined by an earlier object far back
    in the file (a shared wall), and vertices defined after some faces;
  - an object with two textures (two blocks), a duplicate triangle within
    an object (dropped), the same triangle in two objects (kept in both), a
    degenerate triangle.
Each object is a 9 x 9 patch of quads (162 triangles) with some relief, on
a 4 x 4 grid of 30 m cells, so the blocks spread for the shards' cut.
"""
import math
import os
import shutil
import sys

out = sys.argv[1]
png = sys.argv[2] if len(sys.argv) > 2 else None
lines = []
nv = nvt = nvn = 0


def v(x, y, z):
    global nv
    nv += 1
    lines.append("v %.6f %.6f %.6f" % (x, y, z))
    return nv


def vt(s, t):
    global nvt
    nvt += 1
    lines.append("vt %.5f %.5f" % (s, t))
    return nvt


def vn(x, y, z):
    global nvn
    nvn += 1
    lines.append("vn %.5f %.5f %.5f" % (x, y, z))
    return nvn


def patch(cx, cy, style, n=9, size=20.0, h=3.0, seed=1):
    """A patch of n x n quads centred on (cx, cy); returns its vertex grid."""
    ids, uvs = [], []
    nrm = vn(0, 0, 1)
    for j in range(n + 1):
        for i in range(n + 1):
            x = cx + (i / n - 0.5) * size
            y = cy + (j / n - 0.5) * size
            z = h * math.sin(0.7 * i + seed) * math.cos(0.5 * j + 2 * seed)
            ids.append(v(x, y, z))
            uvs.append(vt(i / n, j / n))
    for j in range(n):
        for i in range(n):
            a, b = j * (n + 1) + i, j * (n + 1) + i + 1
            c, d = a + n + 1, b + n + 1
            q = [a, b, d, c]
            if style == "v":
                lines.append("f " + " ".join(str(ids[k]) for k in q))
            elif style == "vt":
                lines.append("f " + " ".join("%d/%d" % (ids[k], uvs[k]) for k in q))
            elif style == "vn":
                lines.append("f " + " ".join("%d//%d" % (ids[k], nrm) for k in q))
            elif style == "neg":
                # relative indices: count back from the last defined
                lines.append("f " + " ".join("%d/%d/%d" % (ids[k] - nv - 1, uvs[k] - nvt - 1, -1)
                                             for k in q))
            else:
                lines.append("f " + " ".join("%d/%d/%d" % (ids[k], uvs[k], nrm) for k in q))
    return ids, uvs


def cell(k):
    return (k % 4) * 30.0, (k // 4) * 30.0


lines.append("# hlod tests: OBJ corner cases (tests/obj_corner_cases.py)")
# 0: before any o/g and any usemtl: named after the file, material "default"
x, y = cell(0)
patch(x, y, "v", seed=0)
lines.append("usemtl brick")          # defined by a library named further down
lines.append("o first_named")
x, y = cell(1)
first_ids, first_uvs = patch(x, y, "vt", seed=1)
lines.append("mtllib corners.mtl")
lines.append("o empty_object")         # no faces: dropped
lines.append("g group_line")
lines.append("usemtl roof")
x, y = cell(2)
patch(x, y, "vn", seed=2)
lines.append("o relative_indices")
lines.append("usemtl brick")
x, y = cell(3)
patch(x, y, "neg", seed=3)
lines.append("o two_textures")
x, y = cell(4)
ids, uvs = patch(x, y, "full", seed=4)
lines.append("usemtl brick2")          # a second texture: a second block
for k in range(3):  # (not a triangle of the patch: that would be a duplicate)
    a, b, c = ids[k], ids[k + 2], ids[k + 21]
    lines.append("f %d/%d %d/%d %d/%d" % (a, uvs[k], b, uvs[k + 2], c, uvs[k + 21]))
lines.append("usemtl undefined_material")
x, y = cell(5)
lines.append("o shared_wall")          # uses the first object's vertices
ids5, _ = patch(x, y, "v", seed=5)
for k in range(8):
    lines.append("f %d %d %d" % (first_ids[k], first_ids[k + 1], ids5[k]))
lines.append("o later_vertices")       # faces before some of their vertices
x, y = cell(6)
ids6, _ = patch(x, y, "v", seed=6)
lines.append("f %d %d %d" % (ids6[0], ids6[1], ids6[12]))
lines.append("f %d %d %d" % (ids6[12], ids6[1], ids6[0]))  # duplicate, other winding
lines.append("f %d %d %d" % (ids6[0], ids6[0], ids6[1]))   # degenerate
late = [v(x + 12, y + 12, 5), v(x + 14, y + 12, 5), v(x + 13, y + 14, 6), v(x + 12, y + 15, 5.5)]
lines.append("f %d %d %d %d %d" % (late[0], late[1], late[2], late[3], ids6[-1]))  # pentagon
lines.append("o same_triangle_again")  # a triangle of object later_vertices, again
x, y = cell(7)
patch(x, y, "v", seed=7)
lines.append("f %d %d %d" % (ids6[0], ids6[1], ids6[12]))
for k in range(8, 16):
    lines.append("o plain_%d" % k)
    lines.append("usemtl %s" % ("roof" if k % 2 else "brick"))
    x, y = cell(k)
    patch(x, y, "full" if k % 3 else "vt", seed=k)

os.makedirs(out, exist_ok=True)
with open(os.path.join(out, "corners.obj"), "w") as f:
    f.write("\n".join(lines) + "\n")
mtl = ["newmtl brick", "Kd 0.7 0.3 0.2", "newmtl roof", "Kd 0.3 0.3 0.35",
       "newmtl brick2", "Kd 0.6 0.6 0.5"]
if png:
    shutil.copy(png, os.path.join(out, "corners_a.png"))
    shutil.copy(png, os.path.join(out, "corners_b.png"))
    mtl.insert(2, "map_Kd corners_a.png")
    mtl.append("map_Kd corners_b.png")
with open(os.path.join(out, "corners.mtl"), "w") as f:
    f.write("\n".join(mtl) + "\n")
