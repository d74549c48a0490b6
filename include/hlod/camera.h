/*
 * camera.h - the camera the engine and the renderer share.
 */
#ifndef HLOD_CAMERA_H
#define HLOD_CAMERA_H

#include "hlod/hlod.h"

#ifdef __cplusplus
extern "C" {
#endif

/* A camera: eye position in model units (double), plus a view rotation and
 * projection that work in camera-relative coordinates (eye at 0), which is
 * what the renderer and the frustum test use.  Matrices are column-major
 * (OpenGL).  z is up in the generated city, but nothing here assumes it. */
typedef struct hlod_camera {
    double position[3];     /* eye */
    double view[16];        /* rotation only: world direction -> eye space */
    double proj[16];        /* perspective */
    uint32_t width, height; /* viewport in pixels */
    double fov_y_deg;       /* vertical field of view, for screen-space error */
} hlod_camera;

/* Fills cam from an eye, a look-at point and an up vector; a perspective of
 * fov_y_deg with near/far planes.  HLOD_ERR_INVALID_ARG (and cam zeroed) for
 * non-finite input, eye == target, up parallel to the view direction,
 * fov outside (0, 180), near <= 0, far <= near or a zero viewport. */
hlod_result hlod_camera_look_at(hlod_camera *cam, const double eye[3], const double target[3],
                                const double up[3], double fov_y_deg, double near_plane,
                                double far_plane, uint32_t width, uint32_t height);

/* The unit view direction (where the camera looks) of a camera. */
void hlod_camera_forward(const hlod_camera *cam, double out[3]);

/* proj * view (column-major): the camera-relative view-projection that the
 * renderer draws with and whose rows give the frustum planes. */
void hlod_camera_view_proj(const hlod_camera *cam, double out[16]);

#ifdef __cplusplus
}
#endif
#endif
