/*
 * union_find.h - a disjoint-set forest over uint32 indices (path halving),
 * for the builders' and the simplifier's connected parts.  Private to
 * preprocess/.
 */
#ifndef HLOD_UNION_FIND_H
#define HLOD_UNION_FIND_H

#include <stdint.h>

/* The root of x's set; halves the path on the way. */
static inline uint32_t uf_find(uint32_t *parent, uint32_t x)
{
    while (parent[x] != x) {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    return x;
}

/* Joins a's and b's sets; the smaller root index stays the root, so the
 * result does not depend on the order of the unions' calls. */
static inline void uf_union(uint32_t *parent, uint32_t a, uint32_t b)
{
    a = uf_find(parent, a);
    b = uf_find(parent, b);
    if (a < b)
        parent[b] = a;
    else if (b < a)
        parent[a] = b;
}

#endif
