/* Placeholder while the real simplifier is written in this session. */
#include "hlod/simplify.h"
hlod_result hlod_simplify(const hlod_mesh *in, const hlod_simplify_desc *desc,
                          hlod_mesh *out, hlod_simplify_stats *stats)
{
    (void)desc;
    (void)stats;
    return hlod_mesh_copy(out, in);
}
