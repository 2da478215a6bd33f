// expert.cpp — the paper's identification written for Ceres Solver the way its experts write it,
// as the reference volver's native engine is measured against (`bench`, feature `ceres`).
//
// The problem: the XCFZ grinder of Aguado et al. (2014), eq. 11, error module loss (eq. 12).
// Written as a Ceres user who knows the problem would:
//
// * The regressors are fixed. Every error value at a point is linear in its coefficients (cubic
//   Legendre polynomials, first-harmonic Fourier series, constants), so the basis values of every
//   point are computed once, before the solve (by the caller: it has the bases), with the
//   model's linear equality constraints (an error vanishing at its reference position, held
//   parameters) eliminated by substitution. A cost function then forms the 26 values of a point
//   (20 errors, 6 tracker pose values) from the free coefficients by a sparse dot product.
// * AutoDiff where it pays: the chain of eq. 11 is templated and evaluated once per point with a
//   `ceres::Jet<double, 26>` over those 26 values; the Jacobian with respect to the coefficients
//   is then the chain rule (one multiply per coefficient and residual), instead of a Jet as wide
//   as the parameter vector.
// * One dense parameter block, `DENSE_NORMAL_CHOLESKY` (the normal matrix is ~60 × 60 and dense:
//   every coefficient acts at every point), Levenberg–Marquardt, Ceres' default tolerances.
// * The error module as a loss: ρ(s) = 2(√(s + ε²) − ε), so that Ceres' cost ½ Σ ρ(‖r_i‖²) is
//   Σ (‖r_i‖_ε − ε); Ceres applies its own Triggs correction to the Gauss–Newton model.
//
// C ABI only (called from Rust); nothing throws across it.

#include <ceres/ceres.h>
#include <glog/logging.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <mutex>
#include <string>
#include <vector>

extern "C" {
// What the caller gives: the machine's constants and, per point, its commands, reflector,
// measurement and fixed regressors.
struct volver_expert_problem {
    // Axes in chain order X (workpiece side), C (workpiece side), Z (tool side).
    double offset[3][3];
    double z_reference;  // mm
    double base_rotation[3][3];
    // Value s < 20: the axis (0 X, 1 C, 2 Z), whether it is a location error (the squareness
    // of Z: A0Z, B0Z) and its component (EX EY EZ EA EB EC → 0 … 5).
    int slot_axis[20];
    int slot_location[20];
    int slot_component[20];
    int points;
    int free;
    const double *commands;    // points × 3: X mm, C rad, Z mm
    const double *reflectors;  // points × 3: offset in the frame of Z, mm
    const double *measured;    // points × 3, tracker frame, mm
    const double *constant;    // points × 26: each value's part no free coefficient moves
    const double *regressor;   // points × free: each free coefficient's factor in its value
    const int *slot_of;        // free: the value each free coefficient enters
};
}

namespace {

constexpr int kSlots = 26;   // 20 error values, then the tracker x, y, z, rx, ry, rz
constexpr int kErrors = 20;

using Data = volver_expert_problem;

template <typename T>
void cross(const T a[3], const T b[3], T out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

// R(w) v = v − w × v (eq. 4).
template <typename T>
void rot_err(const T w[3], const T v[3], T out[3]) {
    T c[3];
    cross(w, v, c);
    for (int i = 0; i < 3; ++i) out[i] = v[i] - c[i];
}

// R(w)⁻¹ v, exactly: (v + w × v + w (w·v)) / (1 + |w|²).
template <typename T>
void rot_err_inv(const T w[3], const T v[3], T out[3]) {
    T c[3];
    cross(w, v, c);
    const T wv = w[0] * v[0] + w[1] * v[1] + w[2] * v[2];
    const T inv = T(1.0) / (T(1.0) + w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    for (int i = 0; i < 3; ++i) out[i] = (v[i] + c[i] + w[i] * wv) * inv;
}

// Eq. 11 for XCFZ with the tracker on the workpiece side: the reflector carried out through Z
// into the frame, in through X and C into the turntable's frame, then into the tracker's.
template <typename T>
void predict(const Data &d, int i, const T v[kSlots], T out[3]) {
    T comp[3][6], loc[3][6];
    for (int k = 0; k < 3; ++k)
        for (int c = 0; c < 6; ++c) comp[k][c] = loc[k][c] = T(0.0);
    for (int s = 0; s < kErrors; ++s) {
        if (d.slot_location[s])
            loc[d.slot_axis[s]][d.slot_component[s]] = v[s];
        else
            comp[d.slot_axis[s]][d.slot_component[s]] = v[s];
    }
    const double *u = d.commands + 3 * i;
    const double *refl = d.reflectors + 3 * i;
    // Z, tool side (+1): q ↦ O + E + u e_z − squareness × (u − ref) + R⁻¹(w) q.
    T p[3] = {T(refl[0]), T(refl[1]), T(refl[2])};
    {
        const double rel = u[2] - d.z_reference;
        T t[3] = {comp[2][0] + d.offset[2][0], comp[2][1] + d.offset[2][1],
                  comp[2][2] + d.offset[2][2] + u[2]};
        t[1] -= loc[2][3] * rel;  // A0Z
        t[0] -= loc[2][4] * rel;  // B0Z
        T q[3];
        rot_err_inv(&comp[2][3], p, q);
        for (int j = 0; j < 3; ++j) p[j] = t[j] + q[j];
    }
    // X, workpiece side (−1): p ↦ R(w) (p − t), t = O + E − u e_x.
    {
        T t[3] = {comp[0][0] + d.offset[0][0] - u[0], comp[0][1] + d.offset[0][1],
                  comp[0][2] + d.offset[0][2]};
        T q[3] = {p[0] - t[0], p[1] - t[1], p[2] - t[2]};
        rot_err(&comp[0][3], q, p);
    }
    // C, workpiece side: p ↦ Rg(+c) R(w) (p − t), t = O + E.
    {
        T t[3] = {comp[1][0] + d.offset[1][0], comp[1][1] + d.offset[1][1],
                  comp[1][2] + d.offset[1][2]};
        T q[3] = {p[0] - t[0], p[1] - t[1], p[2] - t[2]};
        T r[3];
        rot_err(&comp[1][3], q, r);
        const double s = std::sin(u[1]), c = std::cos(u[1]);
        p[0] = r[0] * c - r[1] * s;
        p[1] = r[0] * s + r[1] * c;
        p[2] = r[2];
    }
    // Tracker: R⁻¹(LT) R0ᵀ (p − T_LT).
    T dd[3] = {p[0] - v[kErrors], p[1] - v[kErrors + 1], p[2] - v[kErrors + 2]};
    T local[3];
    for (int j = 0; j < 3; ++j)
        local[j] = dd[0] * d.base_rotation[0][j] + dd[1] * d.base_rotation[1][j] +
                   dd[2] * d.base_rotation[2][j];
    rot_err_inv(&v[kErrors + 3], local, out);
}

// The 26 values of point i at the free coefficients z.
void values(const Data &d, int i, const double *z, double v[kSlots]) {
    const double *c = d.constant + static_cast<size_t>(kSlots) * i;
    for (int s = 0; s < kSlots; ++s) v[s] = c[s];
    const double *g = d.regressor + static_cast<size_t>(d.free) * i;
    for (int k = 0; k < d.free; ++k) v[d.slot_of[k]] += g[k] * z[k];
}

class PointCost : public ceres::CostFunction {
  public:
    PointCost(const Data *d, int i) : d_(d), i_(i) {
        set_num_residuals(3);
        mutable_parameter_block_sizes()->push_back(d->free);
    }
    bool Evaluate(double const *const *parameters, double *residuals,
                  double **jacobians) const override {
        double v[kSlots];
        values(*d_, i_, parameters[0], v);
        const double *m = d_->measured + 3 * i_;
        if (jacobians == nullptr || jacobians[0] == nullptr) {
            double x[3];
            predict(*d_, i_, v, x);
            for (int j = 0; j < 3; ++j) residuals[j] = x[j] - m[j];
            return true;
        }
        using J = ceres::Jet<double, kSlots>;
        J vj[kSlots];
        for (int s = 0; s < kSlots; ++s) vj[s] = J(v[s], s);
        J x[3];
        predict(*d_, i_, vj, x);
        const int n = d_->free;
        const double *g = d_->regressor + static_cast<size_t>(n) * i_;
        for (int j = 0; j < 3; ++j) {
            residuals[j] = x[j].a - m[j];
            double *row = jacobians[0] + static_cast<size_t>(j) * n;
            for (int k = 0; k < n; ++k) row[k] = x[j].v[d_->slot_of[k]] * g[k];
        }
        return true;
    }

  private:
    const Data *d_;
    int i_;
};

// ρ(s) = 2 (√(s + ε²) − ε).
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

class Record : public ceres::IterationCallback {
  public:
    Record(std::vector<double> *t, std::vector<double> *c) : t_(t), c_(c) {}
    ceres::CallbackReturnType operator()(const ceres::IterationSummary &s) override {
        t_->push_back(s.cumulative_time_in_seconds);
        c_->push_back(s.cost);
        return ceres::SOLVER_CONTINUE;
    }

  private:
    std::vector<double> *t_, *c_;
};

thread_local std::string message;

}  // namespace

extern "C" {


// What a fit gives back (arrays of `max_trace` entries filled up to `trace_len`).
struct volver_expert_result {
    int iterations;          // Ceres' iterations (successful and unsuccessful steps)
    int converged;           // 1 when Ceres reports CONVERGENCE
    double solve_s;          // wall time of Solve (problem built and solved)
    double initial_emm_mm;   // mean ‖r_i‖ at the start
    double final_emm_mm;     // mean ‖r_i‖ at the end (exact, not smoothed)
    int trace_len;
    double *trace_time_s;    // per iteration: cumulative time
    double *trace_cost;      // per iteration: Ceres' cost Σ (‖r_i‖_ε − ε)
    int max_trace;
};

double volver_expert_emm(const volver_expert_problem *p, const double *z) {
    const Data &d = *p;
    double sum = 0.0;
    for (int i = 0; i < d.points; ++i) {
        double v[kSlots], x[3];
        values(d, i, z, v);
        predict(d, i, v, x);
        const double *m = d.measured + 3 * i;
        sum += std::sqrt((x[0] - m[0]) * (x[0] - m[0]) + (x[1] - m[1]) * (x[1] - m[1]) +
                         (x[2] - m[2]) * (x[2] - m[2]));
    }
    return sum / d.points;
}

// Fits `z` (in: the start, out: the end) with `threads` threads and the module loss at `eps` mm.
// Returns 0, or 1 with a message in `volver_expert_message()`.
int volver_expert_fit(const volver_expert_problem *p, double *z, int threads, double eps,
                      volver_expert_result *out) {
    try {
        static std::once_flag once;
        std::call_once(once, [] {
            if (!google::IsGoogleLoggingInitialized()) google::InitGoogleLogging("volver-expert");
            FLAGS_logtostderr = true;
            FLAGS_minloglevel = google::GLOG_ERROR;
        });
        const Data *d = p;
        out->initial_emm_mm = volver_expert_emm(p, z);
        const auto t0 = std::chrono::steady_clock::now();
        ceres::Problem::Options po;
        po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
        ceres::Problem problem(po);
        ModuleLoss loss(eps);
        for (int i = 0; i < d->points; ++i)
            problem.AddResidualBlock(new PointCost(d, i), &loss, z);
        ceres::Solver::Options options;
        options.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
        options.num_threads = threads;
        options.logging_type = ceres::SILENT;
        std::vector<double> times, costs;
        Record record(&times, &costs);
        options.callbacks.push_back(&record);
        ceres::Solver::Summary summary;
        ceres::Solve(options, &problem, &summary);
        out->solve_s =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        out->iterations = summary.num_successful_steps + summary.num_unsuccessful_steps;
        out->converged = summary.termination_type == ceres::CONVERGENCE ? 1 : 0;
        out->final_emm_mm = volver_expert_emm(p, z);
        out->trace_len = 0;
        for (size_t k = 0; k < times.size() && static_cast<int>(k) < out->max_trace; ++k) {
            out->trace_time_s[k] = times[k];
            out->trace_cost[k] = costs[k];
            out->trace_len = static_cast<int>(k) + 1;
        }
        message = summary.message;
        return 0;
    } catch (const std::exception &e) {
        message = e.what();
        return 1;
    }
}

// Ceres' own words on the last fit (its termination message), or the last failure.
const char *volver_expert_message() { return message.c_str(); }

}  // extern "C"
