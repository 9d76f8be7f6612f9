/* The soft silhouette's C kernel (ipm/render/soft.py, backend "native"): the functions Python calls, declared
   once. soft.c defines them (the compiler checks them against these lines) and ipm.native binds them from this
   file (cffi reads the declarations; lines starting with '#' are for the compiler only). _f: float, _d: double.

   Forward. verts (V, 3) with strides vs0, vs1 and the camera cam (13: R (3, 3) row-major, eye (3), focal
   length in pixels, principal point cx, cy): vertices nearer than `near` drop their faces; faces (F, 3) with
   strides fs0, fs1. Writes tri (F, 6) the projected triangles (guarded against non-finite values), rows (F, 2)
   the rows each reaches (j0 > j1 for none), S (H, W + 8) per pixel the sum of log(1 - D), sil (H, W) =
   -expm1(S), on nt threads (adapt: fewer while a thread starts late, see soft_kernel.inc). Returns -1 if a
   vertex index is out of range, -2 when out of memory, else 0.

   Backward. tri, rows, S: from the forward pass; gsil (H, W) = dL/dsil; gS (H, W + 8), gtri (F, 6), gxy (V, 2):
   scratch. Writes gverts (V, 3) = dL/dverts and gcam (13) = dL/dcam (R, eye, focal length; cx, cy are
   constants). */
#include <stdint.h>

int soft_fwd_f(const float *verts, int64_t vs0, int64_t vs1, int64_t V, const float *cam, double near,
               const int64_t *faces, int64_t fs0, int64_t fs1, int64_t F, int W, int H, double r, double sigma,
               double far, float *tri, int32_t *rows, float *S, float *sil, int nt, int adapt);
int soft_fwd_d(const double *verts, int64_t vs0, int64_t vs1, int64_t V, const double *cam, double near,
               const int64_t *faces, int64_t fs0, int64_t fs1, int64_t F, int W, int H, double r, double sigma,
               double far, double *tri, int32_t *rows, double *S, double *sil, int nt, int adapt);
void soft_bwd_f(const float *verts, int64_t vs0, int64_t vs1, int64_t V, const float *cam, const int64_t *faces,
                int64_t fs0, int64_t fs1, int64_t F, int W, int H, double r, double sigma, const float *tri,
                const int32_t *rows, const float *S, const float *gsil, float *gS, float *gtri, float *gxy,
                float *gverts, float *gcam, int nt, int adapt);
void soft_bwd_d(const double *verts, int64_t vs0, int64_t vs1, int64_t V, const double *cam, const int64_t *faces,
                int64_t fs0, int64_t fs1, int64_t F, int W, int H, double r, double sigma, const double *tri,
                const int32_t *rows, const double *S, const double *gsil, double *gS, double *gtri, double *gxy,
                double *gverts, double *gcam, int nt, int adapt);
