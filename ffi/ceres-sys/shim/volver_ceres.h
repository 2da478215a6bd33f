/*
 * volver_ceres.h — the C interface of volver's shim over Ceres Solver (C++).
 *
 * Ceres' own C API (ceres/c_api.h) hard-codes the solver options, prints to stdout and returns
 * no summary; this shim exposes what volver needs instead: one parameter block (the model's
 * parameters), residual blocks evaluated by a callback (residuals and the exact Jacobian block),
 * a loss on every residual block, constant / subset / linear-subspace parameter spaces, the
 * solver options, an iteration callback, and the summary. No function here throws or prints.
 *
 * Every function returns 0 on success and a nonzero code on failure; `volver_ceres_last_error`
 * then holds a message.
 */
#ifndef VOLVER_CERES_H
#define VOLVER_CERES_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* A problem: one parameter block and residual blocks. Opaque. */
typedef struct volver_ceres_problem volver_ceres_problem;

/*
 * Evaluates residual block `block` at `params` (the whole parameter block): writes its residuals
 * and, when `jacobian` is not NULL, its Jacobian (row-major, residuals × parameters). Returns 1
 * on success, 0 when the residuals cannot be evaluated (Ceres then rejects the step).
 */
typedef int (*volver_ceres_cost_fn)(void *user, size_t block, const double *params,
                                    double *residuals, double *jacobian);

/* The loss applied to each residual block's squared norm s. */
typedef enum {
    /* rho(s) = s: plain least squares. */
    VOLVER_CERES_LOSS_NONE = 0,
    /* rho(s) = 2 (sqrt(s + eps^2) - eps): the error module, smoothed by eps (eps > 0). */
    VOLVER_CERES_LOSS_MODULE = 1,
    /* Ceres' SoftLOneLoss(a = eps): rho(s) = 2 a^2 (sqrt(1 + s / a^2) - 1) = eps * MODULE. */
    VOLVER_CERES_LOSS_SOFT_L_ONE = 2
} volver_ceres_loss;

typedef enum {
    VOLVER_CERES_LEVENBERG_MARQUARDT = 0,
    VOLVER_CERES_DOGLEG = 1
} volver_ceres_trust_region;

typedef enum {
    VOLVER_CERES_DENSE_QR = 0,
    VOLVER_CERES_DENSE_NORMAL_CHOLESKY = 1,
    VOLVER_CERES_SPARSE_NORMAL_CHOLESKY = 2,
    VOLVER_CERES_CGNR = 3
} volver_ceres_linear_solver;

/* Solver options (the subset of ceres::Solver::Options volver sets). */
typedef struct {
    volver_ceres_trust_region trust_region;
    volver_ceres_linear_solver linear_solver;
    int max_iterations;
    double function_tolerance;
    double gradient_tolerance;
    double parameter_tolerance;
    double initial_trust_region_radius;
    int num_threads;
    /* 1: scale the columns by their norms (Ceres' default). */
    int jacobi_scaling;
} volver_ceres_options;

/* What the iteration callback sees (from ceres::IterationSummary). */
typedef struct {
    int iteration;
    int step_is_successful;
    double cost;
    double cost_change;
    double gradient_max_norm;
    double step_norm;
    double trust_region_radius;
    double cumulative_time_s;
    /* The parameter block after the iteration (n_params values, valid during the call). */
    const double *params;
} volver_ceres_iteration;

/* Returned by the iteration callback. */
typedef enum {
    VOLVER_CERES_CONTINUE = 0,
    VOLVER_CERES_ABORT = 1,
    VOLVER_CERES_STOP = 2
} volver_ceres_control;

typedef volver_ceres_control (*volver_ceres_iteration_fn)(void *user,
                                                          const volver_ceres_iteration *it);

typedef enum {
    VOLVER_CERES_CONVERGENCE = 0,
    VOLVER_CERES_NO_CONVERGENCE = 1,
    VOLVER_CERES_FAILURE = 2,
    VOLVER_CERES_USER_SUCCESS = 3,
    VOLVER_CERES_USER_FAILURE = 4
} volver_ceres_termination;

/* What a solve reports (from ceres::Solver::Summary). */
typedef struct {
    volver_ceres_termination termination;
    int successful_steps;
    int unsuccessful_steps;
    int residual_evaluations;
    int jacobian_evaluations;
    double initial_cost;
    double final_cost;
    double total_time_s;
    /* Ceres' message, NUL-terminated, truncated to fit. */
    char message[512];
} volver_ceres_summary;

/* The message of the last failure of a shim function on this thread ("" if none). */
const char *volver_ceres_last_error(void);

/*
 * A problem over one parameter block of `n_params` values, copied from `params`, with `n_blocks`
 * residual blocks of `residuals_per_block` residuals each, evaluated by `cost(user, …)`. `user`
 * must outlive the problem. NULL on failure.
 */
volver_ceres_problem *volver_ceres_problem_new(size_t n_params, const double *params,
                                               size_t n_blocks, int residuals_per_block,
                                               volver_ceres_cost_fn cost, void *user,
                                               volver_ceres_loss loss, double loss_epsilon);

void volver_ceres_problem_free(volver_ceres_problem *problem);

/* Changes the loss's eps (LOSS_MODULE and LOSS_SOFT_L_ONE; eps > 0). */
int volver_ceres_set_loss_epsilon(volver_ceres_problem *problem, double epsilon);

/* Holds the whole parameter block constant. */
int volver_ceres_set_constant(volver_ceres_problem *problem);

/* Holds the parameters at `indices` (k of them, distinct, fewer than all) constant. */
int volver_ceres_set_subset(volver_ceres_problem *problem, const int *indices, size_t k);

/*
 * Restricts the parameters to the affine subspace x + B t through their current value:
 * `basis` is row-major n_params × m with orthonormal columns (0 < m <= n_params).
 */
int volver_ceres_set_linear(volver_ceres_problem *problem, const double *basis, size_t m);

/* Copies the parameter block out (n_params values) or in. */
int volver_ceres_get_params(const volver_ceres_problem *problem, double *out);
int volver_ceres_set_params(volver_ceres_problem *problem, const double *params);

/*
 * Solves. `iteration` (may be NULL) is called after every iteration with the parameter block
 * up to date. Fills `summary`.
 */
int volver_ceres_solve(volver_ceres_problem *problem, const volver_ceres_options *options,
                       volver_ceres_iteration_fn iteration, void *iteration_user,
                       volver_ceres_summary *summary);

#ifdef __cplusplus
}
#endif

#endif
