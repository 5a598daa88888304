/* A thin layer over CHOLMOD (SuiteSparse) for eprop's direct solver (src/linalg/direct.rs):
 * one factorisation of a symmetric positive definite matrix given by its upper triangle in
 * compressed columns, and solves with several right-hand sides that reuse their work space.
 * It keeps CHOLMOD's structs on the C side, so the Rust side sees plain pointers. */

#include <stdlib.h>
#include <string.h>
#include <cholmod.h>

typedef struct {
    cholmod_common c;
    cholmod_factor *L;
    cholmod_dense *B, *X, *Y, *E;
    int n;
} eprop_cholmod;

/* Factorises the n x n matrix whose upper triangle is (colp, rowi, val) (compressed columns,
 * rows ascending). supernodal: 0 simplicial LL' (no BLAS: faster for eprop's solves at
 * real-time sizes), 1 supernodal. On success returns the
 * factor and sets *lnz to its entries; on failure returns NULL and sets *status: 1 the matrix
 * is not positive definite, 2 out of memory or another CHOLMOD error, 3 the factor would have
 * more than max_lnz entries (then in *lnz). */
void *eprop_cholmod_factor(int n, const int *colp, const int *rowi, const double *val, int supernodal,
                           double max_lnz, double *lnz, int *status) {
    eprop_cholmod *f = calloc(1, sizeof(eprop_cholmod));
    *status = 2;
    if (!f) return NULL;
    f->n = n;
    cholmod_start(&f->c);
    f->c.print = 0;
    f->c.error_handler = NULL;
    f->c.supernodal = supernodal ? CHOLMOD_SUPERNODAL : CHOLMOD_SIMPLICIAL;
    f->c.final_ll = 1;
    /* one ordering: CHOLMOD's nested dissection (METIS's node separators) down to parts of
     * 64 nodes, ordered by constrained minimum degree. The solves read the factor four times
     * a step, so its entries set the step time; on ten tetgen organ meshes of 1.2k-32k
     * unknowns this ordering's factor had -0.6 % to +0.05 % the entries of the best of the
     * nine orderings CHOLMOD can try (AMD's had up to 60 % more), and its analysis took a
     * quarter of the time that trying all nine did (BENCHMARKS.md, "The fill-reducing
     * ordering"). The METIS these calls reach is the one linked into eprop. */
    f->c.nmethods = 1;
    f->c.method[0].ordering = CHOLMOD_NESDIS;
    f->c.method[0].nd_small = 64;
    int nnz = colp[n];
    cholmod_sparse *A = cholmod_allocate_sparse(n, n, nnz, 1, 1, 1, CHOLMOD_REAL, &f->c);
    if (!A) goto fail;
    memcpy(A->p, colp, sizeof(int) * (size_t)(n + 1));
    memcpy(A->i, rowi, sizeof(int) * (size_t)nnz);
    memcpy(A->x, val, sizeof(double) * (size_t)nnz);
    f->L = cholmod_analyze(A, &f->c);
    if (!f->L) { cholmod_free_sparse(&A, &f->c); goto fail; }
    if (f->c.lnz > max_lnz) {
        /* the analysis's count, before the factor's memory is taken */
        *lnz = f->c.lnz;
        *status = 3;
        cholmod_free_sparse(&A, &f->c);
        goto fail;
    }
    cholmod_factorize(A, f->L, &f->c);
    cholmod_free_sparse(&A, &f->c);
    if (f->c.status == CHOLMOD_NOT_POSDEF) { *status = 1; goto fail; }
    if (f->c.status < CHOLMOD_OK || f->L->minor < (size_t)n) { *status = f->L->minor < (size_t)n ? 1 : 2; goto fail; }
    *lnz = f->c.lnz;
    *status = 0;
    return f;
fail:
    if (f->L) cholmod_free_factor(&f->L, &f->c);
    cholmod_finish(&f->c);
    free(f);
    return NULL;
}

/* Solves A X = B for k right-hand sides, b (n x k, column after column) overwritten by X.
 * Returns 0 on success. */
int eprop_cholmod_solve(void *h, int k, double *b) {
    eprop_cholmod *f = h;
    size_t n = (size_t)f->n;
    if (!f->B || f->B->ncol != (size_t)k) {
        if (f->B) cholmod_free_dense(&f->B, &f->c);
        f->B = cholmod_allocate_dense(n, k, n, CHOLMOD_REAL, &f->c);
        if (!f->B) return 2;
    }
    memcpy(f->B->x, b, sizeof(double) * n * (size_t)k);
    if (!cholmod_solve2(CHOLMOD_A, f->L, f->B, NULL, &f->X, NULL, &f->Y, &f->E, &f->c)) return 2;
    memcpy(b, f->X->x, sizeof(double) * n * (size_t)k);
    return 0;
}

void eprop_cholmod_free(void *h) {
    eprop_cholmod *f = h;
    if (!f) return;
    if (f->B) cholmod_free_dense(&f->B, &f->c);
    if (f->X) cholmod_free_dense(&f->X, &f->c);
    if (f->Y) cholmod_free_dense(&f->Y, &f->c);
    if (f->E) cholmod_free_dense(&f->E, &f->c);
    if (f->L) cholmod_free_factor(&f->L, &f->c);
    cholmod_finish(&f->c);
    free(f);
}
