/* Placeholder: the import/export dispatcher is being written this session. */
#include "hlod/mesh_io.h"
hlod_result hlod_mesh_import(const char *path, const hlod_import_desc *desc,
                             hlod_mesh *out, hlod_import_stats *stats)
{
    (void)path; (void)desc; (void)out; (void)stats;
    return HLOD_ERR_UNSUPPORTED;
}
hlod_result hlod_mesh_export(const char *path, const hlod_mesh *m, const hlod_logger *lg)
{
    (void)path; (void)m; (void)lg;
    return HLOD_ERR_UNSUPPORTED;
}
