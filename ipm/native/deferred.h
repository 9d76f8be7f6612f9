/* The deferred renderer's C kernel (ipm/render/deferred.py, backend "native"): the functions Python calls,
   declared once. deferred.c defines them (the compiler checks them against these lines) and ipm.native binds
   them from this file (cffi reads the declarations; lines starting with '#' are for the compiler only).
   _f: float, _d: double. Every array is contiguous, row-major; pixels are numbered j * W + i.

   dr_zbuf: the exact z-buffer of ipm/render/raster.py. tri (F, 3, 2) projected triangles, tdepth (F, 3) their
   vertices' view-axis depths, fidx (F) the face index of each (float64, as visible_triangles gives them).
   Writes depth (H, W) (inf where empty) and face (H, W) (-1 where empty), on nt threads (bands of rows);
   returns -2 when out of memory, else 0.

   dr_bary_fwd: perspective-correct barycentrics bary (H * W, 3) of the pixel centers in their faces face
   (H * W, -1 where empty: zero there), from the camera-space vertices pc (V, 3), faces (F, 3), focal length
   fpx and principal point (cx, cy). dr_bary_bwd: given gbary (H * W, 3), writes gpc (V, 3) and gfpx (1).

   dr_interp_fwd: out (N, C) = sum_k bary[n, k] attr[faces[face[n], k]] for attr (V, C), background where
   face[n] < 0. dr_interp_bwd: given gout (N, C), writes gattr (V, C) and gbary (N, 3) (each if not null).

   dr_aa_fwd: analytic antialiasing of color (H * W, C) with the face ids face (H * W), the z-buffer zbuf
   (H * W, float64, inf where empty), projected vertices xy (V, 2), faces (F, 3) and silhouette (F, 3) (bytes,
   1 for a silhouette edge); writes out (H * W, C). dr_aa_bwd: given gout, writes gcolor (H * W, C) and
   gxy (V, 2).

   dr_silhouette: which edges of faces (F, 3) are silhouettes seen from eye (3) with vertices verts (V, 3):
   sil (F, 3) bytes, edge k from vertex k to k + 1, 1 where no other face on it faces the eye the same way as
   this one (silhouette_edges in deferred.py); returns -2 when out of memory, else 0. */
#include <stdint.h>

int dr_zbuf(const double *tri, const double *tdepth, const int64_t *fidx, int64_t F, int W, int H,
             double *depth, int64_t *face, int nt);

void dr_bary_fwd_f(const float *pc, const int64_t *faces, const int64_t *face, int W, int H,
                   double fpx, double cx, double cy, float *bary);
void dr_bary_fwd_d(const double *pc, const int64_t *faces, const int64_t *face, int W, int H,
                   double fpx, double cx, double cy, double *bary);
void dr_bary_bwd_f(const float *pc, int64_t V, const int64_t *faces, const int64_t *face, int W, int H,
                   double fpx, double cx, double cy, const float *gbary, float *gpc,
                   float *gfpx);
void dr_bary_bwd_d(const double *pc, int64_t V, const int64_t *faces, const int64_t *face, int W, int H,
                   double fpx, double cx, double cy, const double *gbary, double *gpc,
                   double *gfpx);

void dr_interp_fwd_f(const float *attr, int64_t C, const int64_t *faces, const int64_t *face,
                     const float *bary, int64_t N, double background, float *out);
void dr_interp_fwd_d(const double *attr, int64_t C, const int64_t *faces, const int64_t *face,
                     const double *bary, int64_t N, double background, double *out);
void dr_interp_bwd_f(const float *attr, int64_t V, int64_t C, const int64_t *faces, const int64_t *face,
                     const float *bary, int64_t N, const float *gout, float *gattr, float *gbary);
void dr_interp_bwd_d(const double *attr, int64_t V, int64_t C, const int64_t *faces, const int64_t *face,
                     const double *bary, int64_t N, const double *gout, double *gattr, double *gbary);

void dr_aa_fwd_f(const float *color, int64_t C, const int64_t *face, const double *zbuf, int W, int H,
                 const float *xy, const int64_t *faces, const uint8_t *sil, float *out);
void dr_aa_fwd_d(const double *color, int64_t C, const int64_t *face, const double *zbuf, int W, int H,
                 const double *xy, const int64_t *faces, const uint8_t *sil, double *out);
void dr_aa_bwd_f(const float *color, int64_t C, const int64_t *face, const double *zbuf, int W, int H,
                 const float *xy, int64_t V, const int64_t *faces, const uint8_t *sil, const float *gout,
                 float *gcolor, float *gxy);
void dr_aa_bwd_d(const double *color, int64_t C, const int64_t *face, const double *zbuf, int W, int H,
                 const double *xy, int64_t V, const int64_t *faces, const uint8_t *sil, const double *gout,
                 double *gcolor, double *gxy);

int dr_silhouette_f(const float *verts, int64_t V, const int64_t *faces, int64_t F, const float *eye, uint8_t *sil);
int dr_silhouette_d(const double *verts, int64_t V, const int64_t *faces, int64_t F, const double *eye,
                    uint8_t *sil);
