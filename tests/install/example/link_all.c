/* Takes the address of a function of every installed library, so linking
 * it pulls in each library's objects that need the dependencies (OpenImageIO
 * and C++, assimp, METIS, libcurl, turbojpeg, meshoptimizer, OSMesa, EGL):
 * the package must bring them all.  Running it only checks that it starts. */
#include <hlod/build_store.h>
#include <hlod/engine.h>
#include <hlod/image.h>
#include <hlod/mesh_io.h>
#include <hlod/renderer.h>
#include <hlod/simplify.h>
#include <stdio.h>

typedef void (*any_fn)(void);

int main(void)
{
    any_fn volatile fns[] = {
        (any_fn)hlod_image_read,  (any_fn)hlod_image_write, (any_fn)hlod_mesh_import,
        (any_fn)hlod_simplify,    (any_fn)hlod_build_store, (any_fn)hlod_store_open,
        (any_fn)hlod_engine_create, (any_fn)hlod_osmesa_create,
#ifdef HLOD_EXAMPLE_EGL
        (any_fn)hlod_egl_create,
#endif
    };
    size_t n = sizeof fns / sizeof fns[0];
    for (size_t i = 0; i < n; i++)
        if (!fns[i])
            return 1;
    printf("linked %zu functions\n", n);
    return 0;
}
