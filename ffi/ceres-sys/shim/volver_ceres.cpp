// volver_ceres.cpp — the C++ side of volver's Ceres shim (see volver_ceres.h).
//
// Nothing here throws across the C boundary or prints: every entry point catches C++
// exceptions and records a message, and Ceres' logging is silenced.

#include "volver_ceres.h"

#include <ceres/ceres.h>
#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

namespace {

thread_local std::string last_error;

int fail(const std::string &message) {
    last_error = message;
    return 1;
}

void quiet_logging() {
    static std::once_flag once;
    std::call_once(once, [] {
        if (!google::IsGoogleLoggingInitialized()) {
            google::InitGoogleLogging("volver");
        }
        FLAGS_logtostderr = true;
        FLAGS_minloglevel = google::GLOG_ERROR;
    });
}

// Residual block `block`, evaluated by the Rust callback.
class CallbackCost : public ceres::CostFunction {
  public:
    CallbackCost(size_t block, int n_residuals, int n_params, volver_ceres_cost_fn cost,
                 void *user)
        : block_(block), cost_(cost), user_(user) {
        set_num_residuals(n_residuals);
        mutable_parameter_block_sizes()->push_back(n_params);
    }

    bool Evaluate(double const *const *parameters, double *residuals,
                  double **jacobians) const override {
        double *jacobian = jacobians != nullptr ? jacobians[0] : nullptr;
        return cost_(user_, block_, parameters[0], residuals, jacobian) != 0;
    }

  private:
    size_t block_;
    volver_ceres_cost_fn cost_;
    void *user_;
};

// rho(s) = 2 (sqrt(s + eps^2) - eps): half the sum over blocks is sum_i (‖r_i‖_eps - eps), the
// smoothed error module; eps -> 0 gives rho(s) = 2 sqrt(s).
class ModuleLoss : public ceres::LossFunction {
  public:
    explicit ModuleLoss(double eps) : eps_(eps) {}
    void Evaluate(double s, double rho[3]) const override {
        const double e2 = eps_ * eps_;
        const double q = std::sqrt(s + e2);
        rho[0] = 2.0 * (q - eps_);
        rho[1] = 1.0 / q;
        rho[2] = -0.5 / (q * (s + e2));
    }

  private:
    double eps_;
};

// x + B t through the current point; B has orthonormal columns.
class LinearManifold : public ceres::Manifold {
  public:
    LinearManifold(int n, int m, std::vector<double> basis)
        : n_(n), m_(m), basis_(std::move(basis)) {}
    int AmbientSize() const override { return n_; }
    int TangentSize() const override { return m_; }
    bool Plus(const double *x, const double *delta, double *out) const override {
        for (int i = 0; i < n_; ++i) {
            double v = x[i];
            for (int k = 0; k < m_; ++k) v += basis_[i * m_ + k] * delta[k];
            out[i] = v;
        }
        return true;
    }
    bool PlusJacobian(const double *, double *jacobian) const override {
        std::copy(basis_.begin(), basis_.end(), jacobian);
        return true;
    }
    bool Minus(const double *y, const double *x, double *out) const override {
        for (int k = 0; k < m_; ++k) {
            double v = 0.0;
            for (int i = 0; i < n_; ++i) v += basis_[i * m_ + k] * (y[i] - x[i]);
            out[k] = v;
        }
        return true;
    }
    bool MinusJacobian(const double *, double *jacobian) const override {
        for (int k = 0; k < m_; ++k)
            for (int i = 0; i < n_; ++i) jacobian[k * n_ + i] = basis_[i * m_ + k];
        return true;
    }

  private:
    int n_, m_;
    std::vector<double> basis_;
};

class Callback : public ceres::IterationCallback {
  public:
    Callback(volver_ceres_iteration_fn f, void *user, const double *params)
        : f_(f), user_(user), params_(params) {}
    ceres::CallbackReturnType operator()(const ceres::IterationSummary &s) override {
        volver_ceres_iteration it;
        it.iteration = s.iteration;
        it.step_is_successful = s.step_is_successful ? 1 : 0;
        it.cost = s.cost;
        it.cost_change = s.cost_change;
        it.gradient_max_norm = s.gradient_max_norm;
        it.step_norm = s.step_norm;
        it.trust_region_radius = s.trust_region_radius;
        it.cumulative_time_s = s.cumulative_time_in_seconds;
        it.params = params_;
        switch (f_(user_, &it)) {
        case VOLVER_CERES_ABORT:
            return ceres::SOLVER_ABORT;
        case VOLVER_CERES_STOP:
            return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
        default:
            return ceres::SOLVER_CONTINUE;
        }
    }

  private:
    volver_ceres_iteration_fn f_;
    void *user_;
    const double *params_;
};

}  // namespace

struct volver_ceres_problem {
    std::vector<double> params;
    std::unique_ptr<ceres::LossFunctionWrapper> loss;  // shared by every block, not owned by problem
    volver_ceres_loss loss_kind;
    std::unique_ptr<ceres::Problem> problem;
    bool constant = false;
};

namespace {

ceres::LossFunction *make_loss(volver_ceres_loss kind, double eps) {
    switch (kind) {
    case VOLVER_CERES_LOSS_MODULE:
        return new ModuleLoss(eps);
    case VOLVER_CERES_LOSS_SOFT_L_ONE:
        return new ceres::SoftLOneLoss(eps);
    default:
        return nullptr;
    }
}

bool valid_epsilon(volver_ceres_loss kind, double eps) {
    return kind == VOLVER_CERES_LOSS_NONE || (std::isfinite(eps) && eps > 0.0);
}

}  // namespace

extern "C" {

const char *volver_ceres_last_error(void) { return last_error.c_str(); }

volver_ceres_problem *volver_ceres_problem_new(size_t n_params, const double *params,
                                               size_t n_blocks, int residuals_per_block,
                                               volver_ceres_cost_fn cost, void *user,
                                               volver_ceres_loss loss, double loss_epsilon) {
    try {
        quiet_logging();
        if (n_params == 0 || params == nullptr || cost == nullptr || residuals_per_block <= 0) {
            fail("volver_ceres_problem_new: empty parameter block, no cost callback or no residuals");
            return nullptr;
        }
        if (loss != VOLVER_CERES_LOSS_NONE && loss != VOLVER_CERES_LOSS_MODULE &&
            loss != VOLVER_CERES_LOSS_SOFT_L_ONE) {
            fail("volver_ceres_problem_new: unknown loss");
            return nullptr;
        }
        if (!valid_epsilon(loss, loss_epsilon)) {
            fail("volver_ceres_problem_new: the loss epsilon must be finite and positive");
            return nullptr;
        }
        auto p = std::make_unique<volver_ceres_problem>();
        p->params.assign(params, params + n_params);
        p->loss_kind = loss;
        if (loss != VOLVER_CERES_LOSS_NONE) {
            p->loss = std::make_unique<ceres::LossFunctionWrapper>(make_loss(loss, loss_epsilon),
                                                                   ceres::TAKE_OWNERSHIP);
        }
        ceres::Problem::Options options;
        options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
        options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
        options.manifold_ownership = ceres::TAKE_OWNERSHIP;
        p->problem = std::make_unique<ceres::Problem>(options);
        double *x = p->params.data();
        p->problem->AddParameterBlock(x, static_cast<int>(n_params));
        for (size_t b = 0; b < n_blocks; ++b) {
            p->problem->AddResidualBlock(
                new CallbackCost(b, residuals_per_block, static_cast<int>(n_params), cost, user),
                p->loss.get(), x);
        }
        return p.release();
    } catch (const std::exception &e) {
        fail(std::string("volver_ceres_problem_new: ") + e.what());
        return nullptr;
    } catch (...) {
        fail("volver_ceres_problem_new: unknown C++ exception");
        return nullptr;
    }
}

void volver_ceres_problem_free(volver_ceres_problem *problem) {
    try {
        delete problem;
    } catch (...) {
    }
}

int volver_ceres_set_loss_epsilon(volver_ceres_problem *p, double epsilon) {
    if (p == nullptr) return fail("volver_ceres_set_loss_epsilon: no problem");
    if (p->loss_kind == VOLVER_CERES_LOSS_NONE)
        return fail("volver_ceres_set_loss_epsilon: the problem has no loss");
    if (!valid_epsilon(p->loss_kind, epsilon))
        return fail("volver_ceres_set_loss_epsilon: epsilon must be finite and positive");
    try {
        p->loss->Reset(make_loss(p->loss_kind, epsilon), ceres::TAKE_OWNERSHIP);
        return 0;
    } catch (const std::exception &e) {
        return fail(std::string("volver_ceres_set_loss_epsilon: ") + e.what());
    }
}

int volver_ceres_set_constant(volver_ceres_problem *p) {
    if (p == nullptr) return fail("volver_ceres_set_constant: no problem");
    try {
        p->problem->SetParameterBlockConstant(p->params.data());
        p->constant = true;
        return 0;
    } catch (const std::exception &e) {
        return fail(std::string("volver_ceres_set_constant: ") + e.what());
    }
}

int volver_ceres_set_subset(volver_ceres_problem *p, const int *indices, size_t k) {
    if (p == nullptr) return fail("volver_ceres_set_subset: no problem");
    const int n = static_cast<int>(p->params.size());
    std::set<int> seen;
    for (size_t i = 0; i < k; ++i) {
        if (indices[i] < 0 || indices[i] >= n || !seen.insert(indices[i]).second)
            return fail("volver_ceres_set_subset: indices must be distinct and within the block");
    }
    if (static_cast<int>(k) >= n)
        return fail("volver_ceres_set_subset: every parameter held; use volver_ceres_set_constant");
    try {
        std::vector<int> v(indices, indices + k);
        p->problem->SetManifold(p->params.data(), new ceres::SubsetManifold(n, v));
        return 0;
    } catch (const std::exception &e) {
        return fail(std::string("volver_ceres_set_subset: ") + e.what());
    }
}

int volver_ceres_set_linear(volver_ceres_problem *p, const double *basis, size_t m) {
    if (p == nullptr) return fail("volver_ceres_set_linear: no problem");
    const size_t n = p->params.size();
    if (m == 0 || m > n) return fail("volver_ceres_set_linear: 0 < m <= n_params is required");
    for (size_t i = 0; i < n * m; ++i)
        if (!std::isfinite(basis[i])) return fail("volver_ceres_set_linear: basis not finite");
    try {
        std::vector<double> b(basis, basis + n * m);
        p->problem->SetManifold(p->params.data(),
                                new LinearManifold(static_cast<int>(n), static_cast<int>(m), b));
        return 0;
    } catch (const std::exception &e) {
        return fail(std::string("volver_ceres_set_linear: ") + e.what());
    }
}

int volver_ceres_get_params(const volver_ceres_problem *p, double *out) {
    if (p == nullptr) return fail("volver_ceres_get_params: no problem");
    std::copy(p->params.begin(), p->params.end(), out);
    return 0;
}

int volver_ceres_set_params(volver_ceres_problem *p, const double *params) {
    if (p == nullptr) return fail("volver_ceres_set_params: no problem");
    std::copy(params, params + p->params.size(), p->params.begin());
    return 0;
}

int volver_ceres_solve(volver_ceres_problem *p, const volver_ceres_options *o,
                       volver_ceres_iteration_fn iteration, void *iteration_user,
                       volver_ceres_summary *out) {
    if (p == nullptr || o == nullptr || out == nullptr)
        return fail("volver_ceres_solve: null argument");
    try {
        ceres::Solver::Options options;
        options.trust_region_strategy_type = o->trust_region == VOLVER_CERES_DOGLEG
                                                 ? ceres::DOGLEG
                                                 : ceres::LEVENBERG_MARQUARDT;
        switch (o->linear_solver) {
        case VOLVER_CERES_DENSE_NORMAL_CHOLESKY:
            options.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
            break;
        case VOLVER_CERES_SPARSE_NORMAL_CHOLESKY:
            options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
            break;
        case VOLVER_CERES_CGNR:
            options.linear_solver_type = ceres::CGNR;
            break;
        default:
            options.linear_solver_type = ceres::DENSE_QR;
        }
        options.max_num_iterations = o->max_iterations;
        options.function_tolerance = o->function_tolerance;
        options.gradient_tolerance = o->gradient_tolerance;
        options.parameter_tolerance = o->parameter_tolerance;
        if (o->initial_trust_region_radius > 0.0)
            options.initial_trust_region_radius = o->initial_trust_region_radius;
        options.num_threads = std::max(1, o->num_threads);
        options.jacobi_scaling = o->jacobi_scaling != 0;
        options.logging_type = ceres::SILENT;
        options.minimizer_progress_to_stdout = false;
        std::unique_ptr<Callback> cb;
        if (iteration != nullptr) {
            cb = std::make_unique<Callback>(iteration, iteration_user, p->params.data());
            options.callbacks.push_back(cb.get());
            options.update_state_every_iteration = true;
        }
        std::string why;
        if (!options.IsValid(&why)) return fail("volver_ceres_solve: invalid options: " + why);
        ceres::Solver::Summary s;
        ceres::Solve(options, p->problem.get(), &s);
        switch (s.termination_type) {
        case ceres::CONVERGENCE:
            out->termination = VOLVER_CERES_CONVERGENCE;
            break;
        case ceres::NO_CONVERGENCE:
            out->termination = VOLVER_CERES_NO_CONVERGENCE;
            break;
        case ceres::USER_SUCCESS:
            out->termination = VOLVER_CERES_USER_SUCCESS;
            break;
        case ceres::USER_FAILURE:
            out->termination = VOLVER_CERES_USER_FAILURE;
            break;
        default:
            out->termination = VOLVER_CERES_FAILURE;
        }
        out->successful_steps = s.num_successful_steps;
        out->unsuccessful_steps = s.num_unsuccessful_steps;
        out->residual_evaluations = s.num_residual_evaluations;
        out->jacobian_evaluations = s.num_jacobian_evaluations;
        out->initial_cost = s.initial_cost;
        out->final_cost = s.final_cost;
        out->total_time_s = s.total_time_in_seconds;
        std::memset(out->message, 0, sizeof out->message);
        std::strncpy(out->message, s.message.c_str(), sizeof out->message - 1);
        return 0;
    } catch (const std::exception &e) {
        return fail(std::string("volver_ceres_solve: ") + e.what());
    } catch (...) {
        return fail("volver_ceres_solve: unknown C++ exception");
    }
}

}  // extern "C"
