/* docs/library.md's example ("Using the library"): renders one frame of a store
 * headless (OSMesa) from south of it and prints what it drew.  Exit 0 when
 * the frame drew triangles that cover pixels.  Usage: hlod-example STORE */
#include <hlod/engine.h>
#include <hlod/renderer.h>
#include <stdio.h>

int main(int argc, char **argv)
{
    static unsigned char rgb[320 * 240 * 3];
    hlod_store *st;  hlod_osmesa *gl;  hlod_renderer *r;  hlod_engine *e;  hlod_camera cam;  hlod_frame_stats fs;
    if (argc != 2 || hlod_store_open(argv[1], NULL, &st) || hlod_osmesa_create(320, 240, NULL, &gl) ||
        hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &r))
        return 1;
    hlod_renderer_set_clear_color(r, 0, 0, 0);
    const hlod_store_header *h = hlod_store_get_header(st);
    double at[3], eye[3], up[3] = {0, 0, 1}, size = h->bbox_max[1] - h->bbox_min[1];
    for (int i = 0; i < 3; i++)
        at[i] = eye[i] = (h->bbox_min[i] + h->bbox_max[i]) / 2;
    eye[1] -= 1.5 * size, eye[2] += size;                 /* south of the store, above it */
    hlod_camera_look_at(&cam, eye, at, up, 60, 0.5, 1e5, 320, 240);
    hlod_engine_desc d = {.renderer = r};                 /* every other setting: its default */
    if (hlod_engine_create(st, &d, &e) || hlod_engine_frame(e, &cam, 1.0 / 30, &fs) || hlod_osmesa_read_rgb(gl, rgb))
        return 1;
    long lit = 0;                                         /* pixels that are not the black background */
    for (size_t i = 0; i < sizeof rgb; i += 3)
        lit += (rgb[i] | rgb[i + 1] | rgb[i + 2]) != 0;
    printf("nodes %u triangles %llu pixels %ld\n", fs.nodes_drawn, (unsigned long long)fs.tris_drawn, lit);
    hlod_engine_destroy(e);  hlod_renderer_destroy(r);  hlod_osmesa_destroy(gl);  hlod_store_close(st);
    return fs.tris_drawn > 0 && lit > 0 ? 0 : 1;
}
