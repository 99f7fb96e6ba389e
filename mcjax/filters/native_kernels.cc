// Native CPU kernels of the local EKF and the modified ICF for run_filter, called through
// XLA's FFI (mcjax/filters/native.py builds this file with the machine's C++ compiler, if it
// has one). The equations are those of mcjax/filters/batched.py, which stays the reference
// and the path for float32, for gradients and for machines without a compiler:
//
// * local: the EKF in moment form (docs/equations.md §5.1): x̄ = F x, P̄ = F P Fᵀ + Q;
//   S = H P̄ Hᵀ + R, K = P̄ Hᵀ S⁻¹, x = x̄ + K ν, P = P̄ − K (P̄ Hᵀ)ᵀ.
// * modified ICF: Sun et al. 2011 eqs. 8–12 — Ȳ = P̄⁻¹, ȳ = Ȳ x̄, contributions
//   i = Hᵀ R⁻¹ (ν + H x̄), I = Hᵀ R⁻¹ H weighted by the agent's component size (or 1),
//   L consensus steps with the weights of eq. 11 (or Metropolis, or max-degree), then
//   P = Y⁻¹, x = P y.
//
// h is range–bearing (Sun et al. 2011 §1.3): r = √(dx² + dy²), b = atan2(dy, dx); H = ∂h/∂x,
// with the guards of mcjax.models.sensors.range_bearing (a target on the sensor gives a zero
// bearing row, a zero range gives a zero range row). Step 0 updates the prior without
// predicting. A measurement with a non-finite component is missing: no update (local) or no
// contribution (modified ICF). The adjacency comes as 0/1 bytes (run_filter has checked it).
// Runs are independent: they are split over threads, and every
// run's numbers do not depend on the batch size or the split.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <thread>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

constexpr int D = 4;
constexpr double kPi = 3.14159265358979323846;

struct Model {
  double x0[D], P0[D][D], F[D][D], Q[D][D], R[2][2], Rinv[2][2];
};

double wrap_angle(double a) {  // (−π, π], as mcjax.numerics.wrap_angle
  if (a > -kPi && a <= kPi) return a;
  double m = std::fmod(a + kPi, 2.0 * kPi);
  if (m < 0) m += 2.0 * kPi;
  double w = m - kPi;
  return w == -kPi ? kPi : w;
}

void predict(const Model& m, bool first, double x[D], double P[D][D]) {
  if (first) return;
  double xb[D], FP[D][D];
  for (int i = 0; i < D; ++i) {
    xb[i] = 0;
    for (int k = 0; k < D; ++k) xb[i] += m.F[i][k] * x[k];
  }
  for (int i = 0; i < D; ++i)
    for (int j = 0; j < D; ++j) {
      FP[i][j] = 0;
      for (int k = 0; k < D; ++k) FP[i][j] += m.F[i][k] * P[k][j];
    }
  for (int i = 0; i < D; ++i) {
    x[i] = xb[i];
    for (int j = i; j < D; ++j) {
      double v = 0;
      for (int k = 0; k < D; ++k) v += FP[i][k] * m.F[j][k];
      P[i][j] = P[j][i] = v + m.Q[i][j];
    }
  }
}

// h(x̄) and H at x̄ for a sensor at (sx, sy); returns false if z is missing.
bool measured(const double* z, const double* s, const double x[D], double nu[2], double H[2][D]) {
  if (!std::isfinite(z[0]) || !std::isfinite(z[1])) return false;
  double dx = x[0] - s[0], dy = x[2] - s[1];
  double sq = dx * dx + dy * dy;
  bool positive = !(sq <= 1e-30);
  double r = positive ? std::sqrt(sq) : 0.0;
  bool on = dx == 0.0 && dy == 0.0;
  double b = on ? 0.0 : std::atan2(dy, dx);
  for (int a = 0; a < 2; ++a)
    for (int k = 0; k < D; ++k) H[a][k] = 0.0;
  if (positive) {
    H[0][0] = dx / r;
    H[0][2] = dy / r;
  }
  if (!on) {
    H[1][0] = -dy / sq;
    H[1][2] = dx / sq;
  }
  nu[0] = z[0] - r;
  nu[1] = wrap_angle(z[1] - b);
  return true;
}

// S⁻¹ of a symmetric positive definite 4×4 by Cholesky S = L Lᵀ, S⁻¹ = L⁻ᵀ L⁻¹ (the algorithm
// of mcjax.numerics.spd_inverse; NaN if S is not positive definite).
void spd_inverse(const double S[D][D], double out[D][D]) {
  double L[D][D] = {}, M[D][D] = {};
  for (int j = 0; j < D; ++j) {
    double d = S[j][j];
    for (int k = 0; k < j; ++k) d -= L[j][k] * L[j][k];
    L[j][j] = std::sqrt(d);
    for (int i = j + 1; i < D; ++i) {
      double v = S[i][j];
      for (int k = 0; k < j; ++k) v -= L[i][k] * L[j][k];
      L[i][j] = v / L[j][j];
    }
  }
  for (int i = 0; i < D; ++i) {
    M[i][i] = 1.0 / L[i][i];
    for (int j = 0; j < i; ++j) {
      double v = 0;
      for (int k = j; k < i; ++k) v += L[i][k] * M[k][j];
      M[i][j] = -v / L[i][i];
    }
  }
  for (int i = 0; i < D; ++i)
    for (int j = i; j < D; ++j) {
      double v = 0;
      for (int k = j; k < D; ++k) v += M[k][i] * M[k][j];
      out[i][j] = out[j][i] = v;
    }
}

void write(double* xs, double* Ps, const double x[D], const double P[D][D]) {
  for (int i = 0; i < D; ++i) xs[i] = x[i];
  for (int i = 0; i < D; ++i)
    for (int j = 0; j < D; ++j) Ps[i * D + j] = P[i][j];
}

// The local EKF on V (run, agent) lanes at once, the state in structure-of-arrays form, so
// that the compiler turns every lane loop into vector instructions (atan2, a library call,
// runs lane by lane). Lanes are the flattened (run, agent) pairs lane0 … lane0 + V − 1; a
// block past the last pair repeats the last pair and writes nothing for it, so every pair is
// computed by the same instructions whatever the batch size. H has the zero columns 1 and 3
// of range–bearing (h depends on the position only); a missing measurement keeps the
// prediction (a select, not a branch).
constexpr int V = 8;

void local_block(const Model& m, const double* z, const double* s, int64_t lane0, int64_t total, int64_t T,
                 int64_t n, double* xs, double* Ps) {
  int64_t base[V];
  bool live[V];
  for (int l = 0; l < V; ++l) {
    int64_t lane = std::min(lane0 + l, total - 1);
    live[l] = lane0 + l < total;
    base[l] = (lane / n) * T * n + lane % n;  // row of step 0: ((b T) + t) n + i
  }
  alignas(64) double x[D][V], P[D][D][V];
  for (int k = 0; k < D; ++k)
    for (int l = 0; l < V; ++l) x[k][l] = m.x0[k];
  for (int k = 0; k < D; ++k)
    for (int q = 0; q < D; ++q)
      for (int l = 0; l < V; ++l) P[k][q][l] = m.P0[k][q];
  for (int64_t t = 0; t < T; ++t) {
    if (t > 0) {
      alignas(64) double xb[D][V], FP[D][D][V];
      for (int i = 0; i < D; ++i)
        for (int l = 0; l < V; ++l) {
          double v = 0;
          for (int k = 0; k < D; ++k) v += m.F[i][k] * x[k][l];
          xb[i][l] = v;
        }
      for (int i = 0; i < D; ++i)
        for (int q = 0; q < D; ++q)
          for (int l = 0; l < V; ++l) {
            double v = 0;
            for (int k = 0; k < D; ++k) v += m.F[i][k] * P[k][q][l];
            FP[i][q][l] = v;
          }
      for (int i = 0; i < D; ++i)
        for (int l = 0; l < V; ++l) x[i][l] = xb[i][l];
      for (int i = 0; i < D; ++i)
        for (int q = i; q < D; ++q)
          for (int l = 0; l < V; ++l) {
            double v = 0;
            for (int k = 0; k < D; ++k) v += FP[i][k][l] * m.F[q][k];
            P[i][q][l] = P[q][i][l] = v + m.Q[i][q];
          }
    }
    alignas(64) double nu0s[V], nu1s[V], H00[V], H02[V], H10[V], H12[V];
    bool valid[V];
    for (int l = 0; l < V; ++l) {  // lane by lane: h, H and ν (the library's atan2, the wrap)
      int64_t row = base[l] + t * n;
      double xl[D] = {x[0][l], x[1][l], x[2][l], x[3][l]}, nu[2] = {0.0, 0.0}, H[2][D] = {};
      valid[l] = measured(z + 2 * row, s + 2 * row, xl, nu, H);
      nu0s[l] = nu[0];
      nu1s[l] = nu[1];
      H00[l] = H[0][0];
      H02[l] = H[0][2];
      H10[l] = H[1][0];
      H12[l] = H[1][2];
    }
    for (int l = 0; l < V; ++l) {
      double h00 = H00[l], h02 = H02[l], h10 = H10[l], h12 = H12[l], nu0 = nu0s[l], nu1 = nu1s[l];
      double PHt[D][2];
      for (int k = 0; k < D; ++k) {
        PHt[k][0] = P[k][0][l] * h00 + P[k][2][l] * h02;
        PHt[k][1] = P[k][0][l] * h10 + P[k][2][l] * h12;
      }
      double s00 = h00 * PHt[0][0] + h02 * PHt[2][0] + m.R[0][0];
      double s01 = h00 * PHt[0][1] + h02 * PHt[2][1] + 0.5 * (m.R[0][1] + m.R[1][0]);
      double s11 = h10 * PHt[0][1] + h12 * PHt[2][1] + m.R[1][1];
      double det = s00 * s11 - s01 * s01;
      double i00 = s11 / det, i11 = s00 / det, i01 = -s01 / det;
      bool ok = valid[l];
      for (int k = 0; k < D; ++k) {
        double k0 = PHt[k][0] * i00 + PHt[k][1] * i01, k1 = PHt[k][0] * i01 + PHt[k][1] * i11;
        double xn = x[k][l] + (k0 * nu0 + k1 * nu1);
        x[k][l] = ok ? xn : x[k][l];
        for (int q = k; q < D; ++q) {
          double v = P[k][q][l] - (k0 * PHt[q][0] + k1 * PHt[q][1]);
          v = ok ? v : P[k][q][l];
          P[k][q][l] = v;
          P[q][k][l] = v;
        }
      }
    }
    for (int l = 0; l < V; ++l) {
      if (!live[l]) continue;
      int64_t row = base[l] + t * n;
      double* xo = xs + D * row;
      double* po = Ps + D * D * row;
      for (int k = 0; k < D; ++k) xo[k] = x[k][l];
      for (int k = 0; k < D; ++k)
        for (int q = 0; q < D; ++q) po[k * D + q] = P[k][q][l];
    }
  }
}

void local_runs(const Model& m, const double* z, const double* s, int64_t b0, int64_t b1, int64_t T,
                int64_t n, double* xs, double* Ps) {
  // runs b0 … b1 − 1, i.e. lanes b0 n … b1 n − 1, in blocks of V
  int64_t first = b0 * n, last = b1 * n;
  for (int64_t lane = first; lane < last; lane += V)
    local_block(m, z, s, lane, last, T, n, xs, Ps);
}

constexpr int kMaxAgents = 64;

// Consensus weights (0: Sun et al. 2011 eq. 11, 1: Metropolis, 2: max-degree; the functions of
// mcjax.graph) and, if `component`, each agent's connected-component size (else 1).
void graph_terms(const uint8_t* adj, int64_t n, int weights, bool component, double* W, double* size) {
  double d[kMaxAgents];
  for (int64_t i = 0; i < n; ++i) {
    d[i] = 0;
    for (int64_t j = 0; j < n; ++j)
      if (j != i) d[i] += static_cast<double>(adj[i * n + j]);
  }
  for (int64_t i = 0; i < n; ++i) {
    double off = 0;
    for (int64_t j = 0; j < n; ++j) {
      if (j == i) continue;
      double a = static_cast<double>(adj[i * n + j]), w;
      if (weights == 0) w = a / (1.0 + d[i]);
      else if (weights == 1) w = a / (1.0 + std::max(d[i], d[j]));
      else w = a / static_cast<double>(n);
      W[i * n + j] = w;
      off += w;
    }
    if (weights == 0) W[i * n + i] = 1.0 / (1.0 + d[i]);
    else if (weights == 1) W[i * n + i] = 1.0 - off;
    else W[i * n + i] = 1.0 - d[i] / static_cast<double>(n);
  }
  for (int64_t i = 0; i < n; ++i) {
    if (!component) { size[i] = 1.0; continue; }
    bool seen[kMaxAgents] = {};
    int64_t stack[kMaxAgents], top = 0, count = 0;
    stack[top++] = i;
    seen[i] = true;
    while (top) {
      int64_t k = stack[--top];
      ++count;
      for (int64_t j = 0; j < n; ++j)
        if (!seen[j] && j != k && adj[k * n + j] != 0) { seen[j] = true; stack[top++] = j; }
    }
    size[i] = static_cast<double>(count);
  }
}

constexpr int U = 10;  // unique entries of a symmetric 4×4, row-major upper triangle
constexpr int UI[U] = {0, 0, 0, 0, 1, 1, 1, 2, 2, 3};
constexpr int UJ[U] = {0, 1, 2, 3, 1, 2, 3, 2, 3, 3};

void icf_runs(const Model& m, const double* z, const double* s, const uint8_t* adj, int64_t b0, int64_t b1,
              int64_t T, int64_t n, int64_t steps, int weights, bool component, double* xs, double* Ps) {
  std::vector<double> x(n * D), P(n * D * D), info(n * (D + U)), mixed(n * (D + U));
  double W[kMaxAgents * kMaxAgents], size[kMaxAgents];
  for (int64_t b = b0; b < b1; ++b) {
    for (int64_t i = 0; i < n; ++i) {
      for (int k = 0; k < D; ++k) x[i * D + k] = m.x0[k];
      for (int k = 0; k < D * D; ++k) P[i * D * D + k] = m.P0[k / D][k % D];
    }
    for (int64_t t = 0; t < T; ++t) {
      graph_terms(adj + (b * T + t) * n * n, n, weights, component, W, size);
      for (int64_t i = 0; i < n; ++i) {
        int64_t row = (b * T + t) * n + i;
        double xi[D], Pi[D][D], Y[D][D], y[D];
        for (int k = 0; k < D; ++k) xi[k] = x[i * D + k];
        for (int k = 0; k < D; ++k)
          for (int l = 0; l < D; ++l) Pi[k][l] = P[i * D * D + k * D + l];
        predict(m, t == 0, xi, Pi);
        spd_inverse(Pi, Y);
        for (int k = 0; k < D; ++k) {
          y[k] = 0;
          for (int l = 0; l < D; ++l) y[k] += Y[k][l] * xi[l];
        }
        double nu[2], H[2][D];
        if (measured(z + 2 * row, s + 2 * row, xi, nu, H)) {
          double pseudo[2], G[D][2];
          for (int a = 0; a < 2; ++a) {
            pseudo[a] = nu[a];
            for (int k = 0; k < D; ++k) pseudo[a] += H[a][k] * xi[k];
          }
          for (int k = 0; k < D; ++k)
            for (int c = 0; c < 2; ++c) G[k][c] = H[0][k] * m.Rinv[0][c] + H[1][k] * m.Rinv[1][c];
          for (int k = 0; k < D; ++k) y[k] += size[i] * (G[k][0] * pseudo[0] + G[k][1] * pseudo[1]);
          for (int k = 0; k < D; ++k)
            for (int l = k; l < D; ++l) Y[k][l] += size[i] * (G[k][0] * H[0][l] + G[k][1] * H[1][l]);
        }
        double* v = &info[i * (D + U)];
        for (int k = 0; k < D; ++k) v[k] = y[k];
        for (int u = 0; u < U; ++u) v[D + u] = Y[UI[u]][UJ[u]];
      }
      for (int64_t step = 0; step < steps; ++step) {
        for (int64_t i = 0; i < n; ++i)
          for (int c = 0; c < D + U; ++c) {
            double v = 0;
            for (int64_t j = 0; j < n; ++j) v += W[i * n + j] * info[j * (D + U) + c];
            mixed[i * (D + U) + c] = v;
          }
        std::swap(info, mixed);
      }
      for (int64_t i = 0; i < n; ++i) {
        const double* v = &info[i * (D + U)];
        double Y[D][D], Pn[D][D], xn[D];
        for (int u = 0; u < U; ++u) Y[UI[u]][UJ[u]] = Y[UJ[u]][UI[u]] = v[D + u];
        spd_inverse(Y, Pn);
        for (int k = 0; k < D; ++k) {
          xn[k] = 0;
          for (int l = 0; l < D; ++l) xn[k] += Pn[k][l] * v[l];
        }
        for (int k = 0; k < D; ++k) x[i * D + k] = xn[k];
        for (int k = 0; k < D * D; ++k) P[i * D * D + k] = Pn[k / D][k % D];
        int64_t row = (b * T + t) * n + i;
        write(xs + D * row, Ps + D * D * row, xn, Pn);
      }
    }
  }
}

Model model_of(ffi::Buffer<ffi::F64> x0, ffi::Buffer<ffi::F64> P0, ffi::Buffer<ffi::F64> F,
               ffi::Buffer<ffi::F64> Q, ffi::Buffer<ffi::F64> R) {
  Model m;
  for (int i = 0; i < D; ++i) {
    m.x0[i] = x0.typed_data()[i];
    for (int j = 0; j < D; ++j) {
      m.P0[i][j] = 0.5 * (P0.typed_data()[i * D + j] + P0.typed_data()[j * D + i]);
      m.F[i][j] = F.typed_data()[i * D + j];
      m.Q[i][j] = Q.typed_data()[i * D + j];
    }
  }
  for (int a = 0; a < 2; ++a)
    for (int c = 0; c < 2; ++c) m.R[a][c] = R.typed_data()[a * 2 + c];
  double det = m.R[0][0] * m.R[1][1] - m.R[0][1] * m.R[1][0];
  m.Rinv[0][0] = m.R[1][1] / det;
  m.Rinv[1][1] = m.R[0][0] / det;
  m.Rinv[0][1] = -m.R[0][1] / det;
  m.Rinv[1][0] = -m.R[1][0] / det;
  return m;
}

template <typename Work>
void over_threads(int64_t B, int64_t threads, Work work) {
  int64_t k = std::max<int64_t>(1, std::min<int64_t>(threads, B));
  if (k == 1) { work(0, B); return; }
  std::vector<std::thread> pool;
  for (int64_t c = 0; c < k; ++c) pool.emplace_back(work, B * c / k, B * (c + 1) / k);
  for (auto& th : pool) th.join();
}

ffi::Error LocalImpl(ffi::Buffer<ffi::F64> z, ffi::Buffer<ffi::F64> s, ffi::Buffer<ffi::F64> x0,
                     ffi::Buffer<ffi::F64> P0, ffi::Buffer<ffi::F64> F, ffi::Buffer<ffi::F64> Q,
                     ffi::Buffer<ffi::F64> R, int64_t threads, ffi::ResultBuffer<ffi::F64> xs,
                     ffi::ResultBuffer<ffi::F64> Ps) {
  auto dims = z.dimensions();  // (B, T, n, 2)
  int64_t B = dims[0], T = dims[1], n = dims[2];
  Model m = model_of(x0, P0, F, Q, R);
  const double *zp = z.typed_data(), *sp = s.typed_data();
  double *xp = xs->typed_data(), *pp = Ps->typed_data();
  over_threads(B, threads, [&](int64_t b0, int64_t b1) { local_runs(m, zp, sp, b0, b1, T, n, xp, pp); });
  return ffi::Error::Success();
}

ffi::Error IcfImpl(ffi::Buffer<ffi::F64> z, ffi::Buffer<ffi::F64> s, ffi::Buffer<ffi::U8> adj,
                   ffi::Buffer<ffi::F64> x0, ffi::Buffer<ffi::F64> P0, ffi::Buffer<ffi::F64> F,
                   ffi::Buffer<ffi::F64> Q, ffi::Buffer<ffi::F64> R, int64_t threads, int64_t steps,
                   int64_t weights, bool component, ffi::ResultBuffer<ffi::F64> xs,
                   ffi::ResultBuffer<ffi::F64> Ps) {
  auto dims = z.dimensions();
  int64_t B = dims[0], T = dims[1], n = dims[2];
  if (n > kMaxAgents) return ffi::Error::InvalidArgument("mcjax native modified ICF: at most 64 agents");
  Model m = model_of(x0, P0, F, Q, R);
  const double *zp = z.typed_data(), *sp = s.typed_data();
  const uint8_t* ap = adj.typed_data();
  double *xp = xs->typed_data(), *pp = Ps->typed_data();
  over_threads(B, threads, [&](int64_t b0, int64_t b1) {
    icf_runs(m, zp, sp, ap, b0, b1, T, n, steps, static_cast<int>(weights), component, xp, pp);
  });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(McjaxLocalEkf, LocalImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Attr<int64_t>("threads")
                                  .Ret<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>());

XLA_FFI_DEFINE_HANDLER_SYMBOL(McjaxModifiedIcf, IcfImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::U8>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("steps")
                                  .Attr<int64_t>("weights")
                                  .Attr<bool>("component")
                                  .Ret<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>());
