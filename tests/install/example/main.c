/* Renders one frame of a store headless (OSMesa) with the installed hlod
 * and prints what it drew: hlod-example STORE.  Exit 0 when the frame drew
 * triangles that cover pixels.  The README's "Using the library" shows it. */
#include <hlod/engine.h>
#include <hlod/renderer.h>
#include <stdio.h>

int main(int argc, char **argv)
{
    enum { W = 320, H = 240 };
    static unsigned char rgb[W * H * 3];
    hlod_store *st;  hlod_osmesa *gl;  hlod_renderer *r;  hlod_engine *e;
    if (argc != 2 || hlod_store_open(argv[1], NULL, &st) || hlod_osmesa_create(W, H, NULL, &gl) ||
        hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &r))
        return 1;
    hlod_renderer_set_clear_color(r, 0, 0, 0);
    hlod_engine_desc d = {0};  /* zero: every default */
    d.renderer = r;
    if (hlod_engine_create(st, &d, &e))
        return 1;
    const double *lo = hlod_store_get_header(st)->bbox_min, *hi = hlod_store_get_header(st)->bbox_max;
    double at[3] = {(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]}, up[3] = {0, 0, 1};
    double eye[3] = {at[0], at[1] - 1.5 * (hi[1] - lo[1]), hi[2] + (hi[1] - lo[1])};
    hlod_camera cam;
    hlod_camera_look_at(&cam, eye, at, up, 60, 0.5, 1e5, W, H);
    hlod_frame_stats fs;
    if (hlod_engine_frame(e, &cam, 1.0 / 30, &fs) || hlod_osmesa_read_rgb(gl, rgb))
        return 1;
    long lit = 0;
    for (long i = 0; i < W * H; i++)
        lit += (rgb[3 * i] | rgb[3 * i + 1] | rgb[3 * i + 2]) != 0;
    printf("nodes %u triangles %llu pixels %ld\n", fs.nodes_drawn, (unsigned long long)fs.tris_drawn, lit);
    hlod_engine_destroy(e);  hlod_renderer_destroy(r);  hlod_osmesa_destroy(gl);  hlod_store_close(st);
    return fs.tris_drawn > 0 && lit > 0 ? 0 : 1;
}
