/*
 * camera.c - look-at cameras in camera-relative form (engine.h).
 *
 * The view matrix is the rotation part of gluLookAt only: the renderer and
 * the frustum test work with positions relative to the eye (computed in
 * double, then rounded once), so no matrix ever carries a translation of
 * millions of metres into float.  The projection is gluPerspective's.
 * Both are column-major doubles, element (row, col) at [col * 4 + row].
 */
#include <assert.h>
#include <math.h>
#include <string.h>

#include "hlod/camera.h"
#include "hlod/vec3.h"

static int finite3(const double v[3])
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

/* Scales v to unit length; returns 0 (v untouched) when its length is zero
 * or not representable. */
static int normalize(double v[3])
{
    double len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (!(len > 0) || !isfinite(len) || !isfinite(1 / len))
        return 0;
    for (int k = 0; k < 3; k++)
        v[k] /= len;
    return 1;
}

/* called from any thread (pure function of its arguments) */
hlod_result hlod_camera_look_at(hlod_camera *cam, const double eye[3], const double target[3],
                                const double up[3], double fov_y_deg, double near_plane,
                                double far_plane, uint32_t width, uint32_t height)
{
    if (!cam)
        return HLOD_ERR_INVALID_ARG;
    memset(cam, 0, sizeof *cam);
    if (!eye || !target || !up || !finite3(eye) || !finite3(target) || !finite3(up) ||
        !(fov_y_deg > 0 && fov_y_deg < 180) || !(near_plane > 0) || !(far_plane > near_plane) ||
        !isfinite(far_plane) || width == 0 || height == 0)
        return HLOD_ERR_INVALID_ARG;

    /* gluLookAt: f forward, s right, u up; rows of the rotation s, u, -f. */
    double f[3] = {target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]};
    double u[3] = {up[0], up[1], up[2]}, s[3];
    if (!normalize(f) || !normalize(u))
        return HLOD_ERR_INVALID_ARG;
    hlod_cross3(s, f, u);
    /* |s| = sin(angle between f and up): parallel within ~1e-6 degrees is
     * rejected, the basis would be mostly rounding noise */
    if (!(sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) > 1e-8) || !normalize(s))
        return HLOD_ERR_INVALID_ARG;
    hlod_cross3(u, s, f);

    for (int k = 0; k < 3; k++) {
        cam->position[k] = eye[k];
        cam->view[k * 4 + 0] = s[k];
        cam->view[k * 4 + 1] = u[k];
        cam->view[k * 4 + 2] = -f[k];
    }
    cam->view[15] = 1;

    /* gluPerspective */
    double t = 1 / tan(fov_y_deg * (M_PI / 360.0));
    double aspect = (double)width / (double)height;
    cam->proj[0] = t / aspect;
    cam->proj[5] = t;
    cam->proj[10] = (far_plane + near_plane) / (near_plane - far_plane);
    cam->proj[11] = -1;
    cam->proj[14] = 2 * far_plane * near_plane / (near_plane - far_plane);

    cam->width = width;
    cam->height = height;
    cam->fov_y_deg = fov_y_deg;
    return HLOD_OK;
}

/* called from any thread */
void hlod_camera_forward(const hlod_camera *cam, double out[3])
{
    assert(cam && out);
    /* the third row of the rotation is -forward */
    out[0] = -cam->view[2];
    out[1] = -cam->view[6];
    out[2] = -cam->view[10];
}

void hlod_camera_view_proj(const hlod_camera *cam, double out[16])
{
    for (int c = 0; c < 4; c++)
        for (int r = 0; r < 4; r++) {
            double s = 0;
            for (int k = 0; k < 4; k++)
                s += cam->proj[k * 4 + r] * cam->view[c * 4 + k];
            out[c * 4 + r] = s;
        }
}
