/* DGEMMT (C := alpha op(A) op(B) + beta C on the lower or upper triangle of C, the other
   triangle untouched) through DGEMM on column blocks of NB columns: each diagonal block is
   computed whole into a buffer and its triangle added to C, the rest of the block column is
   one DGEMM straight into C. The OpenBLAS of the DOLFINx wheel (0.3.32) computes DGEMMT
   column by column with GEMV, memory-bound, slower than a whole DGEMM of twice the flops;
   MUMPS calls it for the symmetric update of every front in an LDL^T factorization.
   Calls with N <= 2 NB, alpha = 0, K = 0 or arguments it does not know go to OpenBLAS' own
   DGEMMT (OpenBLAS issue 4921). Loaded by benchmarks/blocked_gemmt.py (RTLD_GLOBAL, ahead of
   PETSc) and initialised with the path of the OpenBLAS that PETSc links. */
#include <dlfcn.h>
#include <stddef.h>

#define EXPORT __attribute__((visibility("default")))
#define NB 128

typedef void (*gemm_t)(const char *, const char *, const int *, const int *, const int *,
                       const double *, const double *, const int *, const double *, const int *,
                       const double *, double *, const int *, size_t, size_t);
typedef void (*gemmt_t)(const char *, const char *, const char *, const int *, const int *,
                        const double *, const double *, const int *, const double *,
                        const int *, const double *, double *, const int *, size_t, size_t,
                        size_t);

static gemm_t blas_dgemm = NULL;
static gemmt_t blas_dgemmt = NULL;
static long calls_blocked = 0, calls_forwarded = 0;

EXPORT int shellobstacle_gemmt_init(const char *openblas) {
  void *lib = dlopen(openblas, RTLD_NOW | RTLD_LOCAL);
  if (!lib) return 1;
  blas_dgemm = (gemm_t)dlsym(lib, "dgemm_");
  blas_dgemmt = (gemmt_t)dlsym(lib, "dgemmt_");
  return (blas_dgemm && blas_dgemmt) ? 0 : 2;
}

/* calls taken in blocks (blocked != 0) or passed to OpenBLAS' DGEMMT so far */
EXPORT long shellobstacle_gemmt_calls(int blocked) {
  return __atomic_load_n(blocked ? &calls_blocked : &calls_forwarded, __ATOMIC_RELAXED);
}

static int is(const char *c, char x) { return *c == x || *c == x + 32; }

EXPORT void dgemmt_(const char *uplo, const char *transa, const char *transb, const int *n,
                    const int *k, const double *alpha, const double *a, const int *lda,
                    const double *b, const int *ldb, const double *beta, double *c,
                    const int *ldc, size_t l1, size_t l2, size_t l3) {
  int N = *n, K = *k;
  int lower = is(uplo, 'L'), ta = !is(transa, 'N'), tb = !is(transb, 'N');
  int valid = (lower || is(uplo, 'U')) && (is(transa, 'N') || is(transa, 'T') || is(transa, 'C'))
              && (is(transb, 'N') || is(transb, 'T') || is(transb, 'C'));
  if (!valid || N <= 2 * NB || K == 0 || *alpha == 0.0) {
    __atomic_fetch_add(&calls_forwarded, 1, __ATOMIC_RELAXED);
    blas_dgemmt(uplo, transa, transb, n, k, alpha, a, lda, b, ldb, beta, c, ldc, l1, l2, l3);
    return;
  }
  __atomic_fetch_add(&calls_blocked, 1, __ATOMIC_RELAXED);
  size_t LDA = (size_t)*lda, LDB = (size_t)*ldb, LDC = (size_t)*ldc;
  double t[NB * NB];
  const double zero = 0.0;
  for (int j0 = 0; j0 < N; j0 += NB) {
    int nb = N - j0 < NB ? N - j0 : NB;
    /* rows j0.. of op(A), columns j0.. of op(B) */
    const double *aj = ta ? a + (size_t)j0 * LDA : a + j0;
    const double *bj = tb ? b + j0 : b + (size_t)j0 * LDB;
    /* the diagonal block into t, then its triangle into C */
    blas_dgemm(transa, transb, &nb, &nb, k, alpha, aj, lda, bj, ldb, &zero, t, &nb, 1, 1);
    for (int j = 0; j < nb; j++) {
      int i0 = lower ? j : 0, i1 = lower ? nb : j + 1;
      double *cj = c + (size_t)(j0 + j) * LDC + j0;
      for (int i = i0; i < i1; i++)
        cj[i] = (*beta == 0.0 ? 0.0 : *beta * cj[i]) + t[(size_t)j * nb + i];
    }
    /* the off-diagonal panel: below the block (lower) or above it (upper) */
    int m = lower ? N - j0 - nb : j0;
    if (m > 0) {
      int r0 = lower ? j0 + nb : 0;
      const double *ar = ta ? a + (size_t)r0 * LDA : a + r0;
      blas_dgemm(transa, transb, &m, &nb, k, alpha, ar, lda, bj, ldb, beta,
                 c + (size_t)j0 * LDC + r0, ldc, 1, 1);
    }
  }
}
