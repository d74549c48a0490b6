/*
 * vec3.h - the small 3-vector helpers every part shares, on double[3],
 * output first.
 */
#ifndef HLOD_VEC3_H
#define HLOD_VEC3_H

static inline double hlod_dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* r = a - b */
static inline void hlod_sub3(double r[3], const double a[3], const double b[3])
{
    r[0] = a[0] - b[0];
    r[1] = a[1] - b[1];
    r[2] = a[2] - b[2];
}

/* r = a x b (r must not alias a or b) */
static inline void hlod_cross3(double r[3], const double a[3], const double b[3])
{
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}

#endif
