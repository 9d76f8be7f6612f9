/* The deferred renderer's C kernel: the exact z-buffer (float64, here), and deferred_kernel.inc, written once
   for a type REAL and compiled for float and double (barycentrics, interpolation, antialiasing, forward and
   backward); the exported functions are declared in deferred.h. Built by ipm.native. */
#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

#include "deferred.h"

/* Per triangle what the z-buffer needs: its screen vertices as the scan sees them (non-finite values and
   values beyond +-far made +-far, as span_rows does), the rows it reaches and the plane of 1/z over the
   screen, from the unguarded vertices (raster.py: _inverse_depth_planes). */
typedef struct { double p[6], a, b, c; int64_t j0, j1; } Tri;

static double guard(double v, double far) {
    if (isnan(v)) return far;
    return v > far ? far : (v < -far ? -far : v);
}

static void setup(const double *t, const double *depth, int W, int H, double far, Tri *T) {
    double ymin = INFINITY, ymax = -INFINITY, xmin = INFINITY, xmax = -INFINITY;
    for (int k = 0; k < 6; k++) T->p[k] = guard(t[k], far);
    for (int k = 0; k < 3; k++) {
        ymin = fmin(ymin, T->p[2 * k + 1]); ymax = fmax(ymax, T->p[2 * k + 1]);
        xmin = fmin(xmin, T->p[2 * k]); xmax = fmax(xmax, T->p[2 * k]);
    }
    double a = ceil(ymin - 0.5), b = floor(ymax - 0.5);
    T->j0 = a < 0 ? 0 : (int64_t)a;
    T->j1 = b > H - 1 ? H - 1 : (int64_t)b;
    if (!(xmax >= 0.5 && xmin <= W - 0.5)) T->j1 = T->j0 - 1;
    /* the plane through (x, y, 1/z) at the vertices: n = (p1 - p0) x (p2 - p0), in raster.py's order */
    double iz[3], u[3], v[3];
    for (int k = 0; k < 3; k++) iz[k] = 1.0 / depth[k];
    u[0] = t[2] - t[0]; u[1] = t[3] - t[1]; u[2] = iz[1] - iz[0];
    v[0] = t[4] - t[0]; v[1] = t[5] - t[1]; v[2] = iz[2] - iz[0];
    double nx = u[1] * v[2] - u[2] * v[1], ny = u[2] * v[0] - u[0] * v[2], nz = u[0] * v[1] - u[1] * v[0];
    if (fabs(nz) > 1e-12) {
        T->a = -nx / nz;
        T->b = -ny / nz;
        T->c = iz[0] - T->a * t[0] - T->b * t[1];
    } else {  /* edge-on: a constant, the mean of the vertices' 1/z */
        T->a = T->b = 0;
        T->c = (iz[0] + iz[1] + iz[2]) / 3;
    }
}

/* The columns i0 .. i1 whose centers lie in the triangle on the line y (as scan.py's _line_extents with no
   padding: the vertices on the line and the crossings of the edges that are not flat); i0 > i1 for none. */
static void span(const double *p, double y, int W, double big, int64_t *i0, int64_t *i1) {
    double lo = INFINITY, hi = -INFINITY;
    int hit = 0;
    for (int e = 0; e < 3; e++) {
        double px = p[2 * e], py = p[2 * e + 1], dv = py - y;
        if (!(0.0 - dv * dv < 0)) { lo = fmin(lo, px); hi = fmax(hi, px); hit = 1; }
        double dx = p[2 * ((e + 1) % 3)] - px, dy = p[2 * ((e + 1) % 3) + 1] - py;
        if (dy == 0) continue;
        double s = (y - py) * (1.0 / dy);
        if (s < 0 || s > 1) continue;
        double x = px + s * dx;
        lo = fmin(lo, x); hi = fmax(hi, x); hit = 1;
    }
    if (!hit) { *i0 = 1; *i1 = 0; return; }
    double a = ceil((lo < -2 ? -2 : (lo > big ? big : lo)) - 0.5);
    double b = floor((hi < -2 ? -2 : (hi > big ? big : hi)) - 0.5);
    *i0 = a < 0 ? 0 : (int64_t)a;
    *i1 = b > W - 1 ? W - 1 : (int64_t)b;
}

/* rows ja .. jb: the nearest triangle (largest 1/z, ties to the lower index) per pixel, in zb and best */
static void band(const Tri *T, int64_t F, int W, double big, int64_t ja, int64_t jb, double *zb, int64_t *best) {
    for (int64_t f = 0; f < F; f++) {
        const Tri *t = T + f;
        int64_t j0 = t->j0 > ja ? t->j0 : ja, j1 = t->j1 < jb ? t->j1 : jb;
        for (int64_t j = j0; j <= j1; j++) {
            double y = (double)j + 0.5, r = t->b * y + t->c;
            int64_t i0, i1;
            span(t->p, y, W, big, &i0, &i1);
            double *z = zb + j * W;
            int64_t *o = best + j * W;
            for (int64_t i = i0; i <= i1; i++) {
                double iz = t->a * ((double)i + 0.5) + r;
                if (iz > z[i]) { z[i] = iz; o[i] = f; }
            }
        }
    }
}

/* The exact z-buffer (see deferred.h): bands of rows, each one thread's, the triangles in index order, so the
   result is the same for any thread count. */
int dr_zbuf(const double *tri, const double *tdepth, const int64_t *fidx, int64_t F, int W, int H,
             double *depth, int64_t *face, int nt) {
    double big = (double)(W > H ? W : H) + 2, far = 1e3 * big;
    Tri *T = malloc((F + 1) * sizeof *T);
    int64_t *best = malloc(((int64_t)W * H + 1) * sizeof *best);
    if (!T || !best) {
        free(T);
        free(best);
        return -2;
    }
    for (int64_t f = 0; f < F; f++) setup(tri + 6 * f, tdepth + 3 * f, W, H, far, T + f);
    for (int64_t k = 0; k < (int64_t)W * H; k++) { depth[k] = -1; best[k] = -1; }
    int nb = nt > 1 ? 4 * nt : 1, rows = (H + nb - 1) / nb;
    rows = rows > 0 ? rows : 1;
#pragma omp parallel for num_threads(nt) schedule(dynamic, 1) if (nt > 1)
    for (int b = 0; b < nb; b++) {
        int64_t ja = (int64_t)b * rows, jb = ja + rows - 1 < H - 1 ? ja + rows - 1 : H - 1;
        if (ja <= jb) band(T, F, W, big, ja, jb, depth, best);
    }
    for (int64_t k = 0; k < (int64_t)W * H; k++) {
        int in = depth[k] > 0;
        face[k] = in ? fidx[best[k]] : -1;
        depth[k] = in ? 1.0 / depth[k] : INFINITY;
    }
    free(T);
    free(best);
    return 0;
}

#define REAL float
#define NAME(x) x##_f
#define TINY 1.17549435e-38f
#include "deferred_kernel.inc"
#undef REAL
#undef NAME
#undef TINY

#define REAL double
#define NAME(x) x##_d
#define TINY 2.2250738585072014e-308
#include "deferred_kernel.inc"
