/*
 * scenes.h - Chamberlain's two test models, made procedurally
 * (hlod-gen-scene --kind tree | molecule; docs/hlod-gen-scene.md).
 *
 * Chamberlain et al., section 5 and Table 2: a tree of about 50k
 * triangles and a molecule of spheres of 800 triangles.  Neither model is
 * theirs; both are built so their distant appearance is the
 * "suspension-like" case the paper's cubes model well (a leafy crown,
 * a dense ball of atoms).
 */
#ifndef HLOD_SCENES_H
#define HLOD_SCENES_H

#include "hlod/mesh.h"

#include <stddef.h>
#include <stdint.h>

/* A tree of about `tris` triangles (at least 8,000): a trunk and five
 * levels of branches, three to a fork, as 8-sided tubes (bark), and the
 * rest as leaves, single quads in two greens around the twigs' ends.
 * About 10 model units tall, the trunk's foot at the origin, z up.
 * Objects: "bark", then "leaves_K" of at most 20,000 triangles. */
hlod_result hlod_scene_tree(size_t tris, uint64_t seed, hlod_mesh *out);

/* A molecule of round(tris / 800) atoms (at least 1): unit spheres of 20
 * slices and 21 stacks (800 triangles each) at uniform random points of a
 * ball holding them at a volume share of 0.3, coloured as carbon (60 %),
 * oxygen (20 %), nitrogen (15 %) and sulphur (5 %).  Objects "atoms_K"
 * of 50 atoms each. */
hlod_result hlod_scene_molecule(size_t tris, uint64_t seed, hlod_mesh *out);

#endif
