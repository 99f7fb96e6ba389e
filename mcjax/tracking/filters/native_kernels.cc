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
#include <atomic>
#include <cmath>
#include <cstdint>
#include <thread>
#include <utility>
#include <vector>

#include <sys/mman.h>

#if defined(MCJAX_LIBMVEC)
#include <immintrin.h>
#endif

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

// Both kernels work on V lanes at once, every state entry a vector of V doubles (GCC/Clang
// vector extensions), so that their arithmetic runs as vector instructions whatever the
// compiler's auto-vectoriser decides (only the loads of z and s, the rare angle wrap and, without
// libmvec, atan2 go lane by lane). A block past the last lane repeats the last one and writes
// nothing for it, so every lane is computed by the same instructions whatever the batch size.
constexpr int V = 8;
typedef double vd __attribute__((vector_size(V * sizeof(double))));
typedef int64_t vm __attribute__((vector_size(V * sizeof(int64_t))));

inline vd splat(double v) { return vd{} + v; }
inline vd root(vd v) {
  vd r;
  for (int l = 0; l < V; ++l) r[l] = std::sqrt(v[l]);
  return r;
}

// x̄ = F x, P̄ = F P Fᵀ + Q (P̄ symmetric by construction).
void predict(const Model& m, vd x[D], vd P[D][D]) {
  vd xb[D], FP[D][D];
  for (int i = 0; i < D; ++i) {
    xb[i] = vd{};
    for (int k = 0; k < D; ++k) xb[i] += m.F[i][k] * x[k];
  }
  for (int i = 0; i < D; ++i)
    for (int q = 0; q < D; ++q) {
      FP[i][q] = vd{};
      for (int k = 0; k < D; ++k) FP[i][q] += m.F[i][k] * P[k][q];
    }
  for (int i = 0; i < D; ++i) x[i] = xb[i];
  for (int i = 0; i < D; ++i)
    for (int q = i; q < D; ++q) {
      vd v = vd{};
      for (int k = 0; k < D; ++k) v += FP[i][k] * m.F[q][k];
      P[i][q] = P[q][i] = v + m.Q[i][q];
    }
}

// atan2 of V lanes: glibc's vector math library (libmvec: 8 lanes with AVX-512, 4 with AVX2)
// when native.py could link it, else the scalar library call lane by lane.
#if defined(MCJAX_LIBMVEC) && defined(__AVX512F__)
extern "C" __m512d _ZGVeN8vv_atan2(__m512d, __m512d);
inline vd lane_atan2(vd y, vd x) { return _ZGVeN8vv_atan2(y, x); }
#elif defined(MCJAX_LIBMVEC) && defined(__AVX2__)
extern "C" __m256d _ZGVdN4vv_atan2(__m256d, __m256d);
inline vd lane_atan2(vd y, vd x) {
  __m256d yh[2], xh[2], rh[2];
  __builtin_memcpy(yh, &y, sizeof y);
  __builtin_memcpy(xh, &x, sizeof x);
  for (int h = 0; h < 2; ++h) rh[h] = _ZGVdN4vv_atan2(yh[h], xh[h]);
  vd r;
  __builtin_memcpy(&r, rh, sizeof r);
  return r;
}
#else
inline vd lane_atan2(vd y, vd x) {
  vd r;
  for (int l = 0; l < V; ++l) r[l] = std::atan2(y[l], x[l]);
  return r;
}
#endif

// The measurement terms of V lanes at the predicted states x (lane l reads row rows[l] of z
// and s): ν = z − h(x̄) (bearing wrapped) and the nonzero entries of H = ∂h/∂x (columns 0 and
// 2: h depends on the position only), with the guards of range_bearing; ok = all ones where
// both components of z are finite (elsewhere ν = 0 and H = 0).
struct Terms {
  vd nu0, nu1, h00, h02, h10, h12;
  vm ok;
};

Terms measure_lanes(const double* z, const double* s, const int64_t rows[V], const vd x[D]) {
  vd z0, z1, sx, sy;
  for (int l = 0; l < V; ++l) {
    z0[l] = z[2 * rows[l]];
    z1[l] = z[2 * rows[l] + 1];
    sx[l] = s[2 * rows[l]];
    sy[l] = s[2 * rows[l] + 1];
  }
  vm ok = (z0 - z0 == 0.0) & (z1 - z1 == 0.0);  // finite: inf − inf and NaN − NaN are NaN
  vd dx = x[0] - sx, dy = x[2] - sy;
  vd sq = dx * dx + dy * dy;
  vm positive = !(sq <= 1e-30);
  vm on = (dx == 0.0) & (dy == 0.0);
  vd r = positive ? root(sq) : 0.0;
  vd b = on ? 0.0 : lane_atan2(dy, dx);
  vd zero = vd{};
  Terms t;
  t.ok = ok;
  t.h00 = (ok & positive) ? dx / r : zero;
  t.h02 = (ok & positive) ? dy / r : zero;
  t.h10 = (ok & ~on) ? -dy / sq : zero;
  t.h12 = (ok & ~on) ? dx / sq : zero;
  t.nu0 = ok ? z0 - r : zero;
  vd nu1 = z1 - b;
  for (int l = 0; l < V; ++l)  // wrap to (−π, π] where needed (rare: lane by lane)
    if (ok[l] && !(nu1[l] > -kPi && nu1[l] <= kPi)) nu1[l] = wrap_angle(nu1[l]);
  t.nu1 = ok ? nu1 : zero;
  return t;
}

// S⁻¹ of a symmetric positive definite 4×4 by Cholesky S = L Lᵀ, S⁻¹ = L⁻ᵀ L⁻¹ (the algorithm
// of mcjax.numerics.spd_inverse; NaN if S is not positive definite), lane by lane.
void spd_inverse(const vd S[D][D], vd out[D][D]) {
  vd L[D][D] = {}, M[D][D] = {};
  for (int j = 0; j < D; ++j) {
    vd d = S[j][j];
    for (int k = 0; k < j; ++k) d -= L[j][k] * L[j][k];
    L[j][j] = root(d);
    for (int i = j + 1; i < D; ++i) {
      vd v = S[i][j];
      for (int k = 0; k < j; ++k) v -= L[i][k] * L[j][k];
      L[i][j] = v / L[j][j];
    }
  }
  for (int i = 0; i < D; ++i) {
    M[i][i] = 1.0 / L[i][i];
    for (int j = 0; j < i; ++j) {
      vd v = vd{};
      for (int k = j; k < i; ++k) v += L[i][k] * M[k][j];
      M[i][j] = -v / L[i][i];
    }
  }
  for (int i = 0; i < D; ++i)
    for (int j = i; j < D; ++j) {
      vd v = vd{};
      for (int k = j; k < D; ++k) v += M[k][i] * M[k][j];
      out[i][j] = out[j][i] = v;
    }
}

// Lane l of x and P to the output row `row`.
void write_lane(double* xs, double* Ps, int64_t row, const vd x[D], const vd P[D][D], int l) {
  double* xo = xs + D * row;
  double* po = Ps + D * D * row;
  for (int k = 0; k < D; ++k) xo[k] = x[k][l];
  for (int k = 0; k < D; ++k)
    for (int q = 0; q < D; ++q) po[k * D + q] = P[k][q][l];
}

// The local EKF on V (run, agent) lanes: the flattened pairs lane0 … lane0 + V − 1. Step 0
// updates the prior without predicting; a missing measurement keeps the prediction (a select).
void local_block(const Model& m, const double* z, const double* s, int64_t lane0, int64_t total, int64_t T,
                 int64_t n, double* xs, double* Ps) {
  int64_t base[V], rows[V];
  for (int l = 0; l < V; ++l) {
    int64_t lane = std::min(lane0 + l, total - 1);
    base[l] = (lane / n) * T * n + lane % n;  // row of step 0: ((b T) + t) n + i
  }
  int live = static_cast<int>(std::min<int64_t>(V, total - lane0));
  vd x[D], P[D][D];
  for (int k = 0; k < D; ++k) x[k] = splat(m.x0[k]);
  for (int k = 0; k < D; ++k)
    for (int q = 0; q < D; ++q) P[k][q] = splat(m.P0[k][q]);
  const double r01 = 0.5 * (m.R[0][1] + m.R[1][0]);
  for (int64_t t = 0; t < T; ++t) {
    if (t > 0) predict(m, x, P);
    for (int l = 0; l < V; ++l) rows[l] = base[l] + t * n;
    Terms e = measure_lanes(z, s, rows, x);
    // S = H P̄ Hᵀ + R, K = P̄ Hᵀ S⁻¹, x = x̄ + K ν, P = P̄ − K (P̄ Hᵀ)ᵀ
    vd PHt0[D], PHt1[D];
    for (int k = 0; k < D; ++k) {
      PHt0[k] = P[k][0] * e.h00 + P[k][2] * e.h02;
      PHt1[k] = P[k][0] * e.h10 + P[k][2] * e.h12;
    }
    vd s00 = e.h00 * PHt0[0] + e.h02 * PHt0[2] + m.R[0][0];
    vd s01 = e.h00 * PHt1[0] + e.h02 * PHt1[2] + r01;
    vd s11 = e.h10 * PHt1[0] + e.h12 * PHt1[2] + m.R[1][1];
    vd det = s00 * s11 - s01 * s01;
    vd i00 = s11 / det, i11 = s00 / det, i01 = -s01 / det;
    for (int k = 0; k < D; ++k) {
      vd k0 = PHt0[k] * i00 + PHt1[k] * i01, k1 = PHt0[k] * i01 + PHt1[k] * i11;
      x[k] = e.ok ? x[k] + (k0 * e.nu0 + k1 * e.nu1) : x[k];
      for (int q = k; q < D; ++q) {
        vd v = e.ok ? P[k][q] - (k0 * PHt0[q] + k1 * PHt1[q]) : P[k][q];
        P[k][q] = v;
        P[q][k] = v;
      }
    }
    for (int l = 0; l < live; ++l) write_lane(xs, Ps, rows[l], x, P, l);
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
  if (!component) {
    for (int64_t i = 0; i < n; ++i) size[i] = 1.0;
    return;
  }
  bool seen[kMaxAgents] = {};
  int64_t members[kMaxAgents];
  for (int64_t i = 0; i < n; ++i) {  // each component once: a depth-first search from its first agent
    if (seen[i]) continue;
    int64_t count = 0, top = 0, stack[kMaxAgents];
    stack[top++] = i;
    seen[i] = true;
    while (top) {
      int64_t k = stack[--top];
      members[count++] = k;
      for (int64_t j = 0; j < n; ++j)
        if (!seen[j] && adj[k * n + j] != 0) { seen[j] = true; stack[top++] = j; }
    }
    for (int64_t c = 0; c < count; ++c) size[members[c]] = static_cast<double>(count);
  }
}

constexpr int U = 10;  // unique entries of a symmetric 4×4, row-major upper triangle
constexpr int UI[U] = {0, 0, 0, 0, 1, 1, 1, 2, 2, 3};
constexpr int UJ[U] = {0, 1, 2, 3, 1, 2, 3, 2, 3, 3};

// The modified ICF on V runs at once (lane l: run b0 + l, the last run repeated past b1),
// each run's n agents coupled by its own graph of the step.
void icf_block(const Model& m, const double* z, const double* s, const uint8_t* adj, int64_t b0, int64_t b1,
               int64_t T, int64_t n, int64_t steps, int weights, bool component, double* xs, double* Ps,
               std::vector<vd>& state, std::vector<vd>& info, std::vector<vd>& mixed, std::vector<vd>& W) {
  int64_t runs[V];
  for (int l = 0; l < V; ++l) runs[l] = std::min(b0 + l, b1 - 1);
  int live = static_cast<int>(std::min<int64_t>(V, b1 - b0));
  vd* x = state.data();          // n × D
  vd* P = state.data() + n * D;  // n × D × D
  for (int64_t i = 0; i < n; ++i) {
    for (int k = 0; k < D; ++k) x[i * D + k] = splat(m.x0[k]);
    for (int k = 0; k < D * D; ++k) P[i * D * D + k] = splat(m.P0[k / D][k % D]);
  }
  double Wl[kMaxAgents * kMaxAgents], sizel[kMaxAgents];
  vd size[kMaxAgents];
  for (int64_t t = 0; t < T; ++t) {
    for (int l = 0; l < V; ++l) {  // the graph terms lane by lane
      graph_terms(adj + (runs[l] * T + t) * n * n, n, weights, component, Wl, sizel);
      for (int64_t k = 0; k < n * n; ++k) W[k][l] = Wl[k];
      for (int64_t i = 0; i < n; ++i) size[i][l] = sizel[i];
    }
    for (int64_t i = 0; i < n; ++i) {
      int64_t rows[V];
      for (int l = 0; l < V; ++l) rows[l] = (runs[l] * T + t) * n + i;
      vd xi[D], Pi[D][D], Y[D][D], y[D];
      for (int k = 0; k < D; ++k) xi[k] = x[i * D + k];
      for (int k = 0; k < D; ++k)
        for (int q = 0; q < D; ++q) Pi[k][q] = P[i * D * D + k * D + q];
      if (t > 0) predict(m, xi, Pi);
      spd_inverse(Pi, Y);  // Ȳ = P̄⁻¹, ȳ = Ȳ x̄
      for (int k = 0; k < D; ++k) {
        y[k] = vd{};
        for (int q = 0; q < D; ++q) y[k] += Y[k][q] * xi[q];
      }
      // contributions: i = Hᵀ R⁻¹ (ν + H x̄), I = Hᵀ R⁻¹ H, times the component size
      Terms e = measure_lanes(z, s, rows, xi);
      vd hrow[2][D] = {{e.h00, vd{}, e.h02, vd{}}, {e.h10, vd{}, e.h12, vd{}}};
      vd pseudo[2] = {e.nu0, e.nu1}, G[D][2];
      for (int a = 0; a < 2; ++a)
        for (int k = 0; k < D; ++k) pseudo[a] += hrow[a][k] * xi[k];
      for (int k = 0; k < D; ++k)
        for (int c = 0; c < 2; ++c) G[k][c] = hrow[0][k] * m.Rinv[0][c] + hrow[1][k] * m.Rinv[1][c];
      vd w = size[i];
      for (int k = 0; k < D; ++k) y[k] = e.ok ? y[k] + w * (G[k][0] * pseudo[0] + G[k][1] * pseudo[1]) : y[k];
      for (int k = 0; k < D; ++k)
        for (int q = k; q < D; ++q)
          Y[k][q] = e.ok ? Y[k][q] + w * (G[k][0] * hrow[0][q] + G[k][1] * hrow[1][q]) : Y[k][q];
      vd* v = &info[i * (D + U)];
      for (int k = 0; k < D; ++k) v[k] = y[k];
      for (int u = 0; u < U; ++u) v[D + u] = Y[UI[u]][UJ[u]];
    }
    for (int64_t step = 0; step < steps; ++step) {  // consensus: L steps of the weights W
      for (int64_t i = 0; i < n; ++i)
        for (int c = 0; c < D + U; ++c) {
          vd v = vd{};
          for (int64_t j = 0; j < n; ++j) v += W[i * n + j] * info[j * (D + U) + c];
          mixed[i * (D + U) + c] = v;
        }
      std::swap(info, mixed);
    }
    for (int64_t i = 0; i < n; ++i) {  // P = Y⁻¹, x = P y
      const vd* v = &info[i * (D + U)];
      vd Y[D][D], Pn[D][D], xn[D];
      for (int u = 0; u < U; ++u) Y[UI[u]][UJ[u]] = Y[UJ[u]][UI[u]] = v[D + u];
      spd_inverse(Y, Pn);
      for (int k = 0; k < D; ++k) {
        xn[k] = vd{};
        for (int q = 0; q < D; ++q) xn[k] += Pn[k][q] * v[q];
      }
      for (int k = 0; k < D; ++k) x[i * D + k] = xn[k];
      for (int k = 0; k < D * D; ++k) P[i * D * D + k] = Pn[k / D][k % D];
      for (int l = 0; l < live; ++l) write_lane(xs, Ps, (runs[l] * T + t) * n + i, xn, Pn, l);
    }
  }
}

void icf_runs(const Model& m, const double* z, const double* s, const uint8_t* adj, int64_t b0, int64_t b1,
              int64_t T, int64_t n, int64_t steps, int weights, bool component, double* xs, double* Ps) {
  std::vector<vd> state(n * (D + D * D)), info(n * (D + U)), mixed(n * (D + U)), W(n * n);
  for (int64_t b = b0; b < b1; b += V)
    icf_block(m, z, s, adj, b, b1, T, n, steps, weights, component, xs, Ps, state, info, mixed, W);
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

// Ask the kernel to back a fresh output buffer with 2 MiB pages where it can (Linux with
// transparent huge pages in "madvise" mode): the first write to each 4 KiB page of a large,
// freshly mapped output otherwise costs a page fault, which measured as much CPU time as the
// filter itself. Advice only — nothing changes if the system declines it.
void advise_huge(void* data, int64_t bytes) {
#ifdef MADV_HUGEPAGE
  constexpr uintptr_t kHuge = uintptr_t{1} << 21;
  uintptr_t lo = (reinterpret_cast<uintptr_t>(data) + kHuge - 1) & ~(kHuge - 1);
  uintptr_t hi = (reinterpret_cast<uintptr_t>(data) + static_cast<uintptr_t>(bytes)) & ~(kHuge - 1);
  if (hi > lo) madvise(reinterpret_cast<void*>(lo), hi - lo, MADV_HUGEPAGE);
#endif
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
  advise_huge(xp, xs->size_bytes());
  advise_huge(pp, Ps->size_bytes());
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
  advise_huge(xp, xs->size_bytes());
  advise_huge(pp, Ps->size_bytes());
  over_threads(B, threads, [&](int64_t b0, int64_t b1) {
    icf_runs(m, zp, sp, ap, b0, b1, T, n, steps, static_cast<int>(weights), component, xp, pp);
  });
  return ffi::Error::Success();
}

}  // namespace

// run_filter's checks of a float64 adjacency (mats n×n matrices, C order) in one pass over
// threads, writing its 0/1 bytes to out (1 where the entry is 1, else 0). Returns a bit set: 1 an
// entry other than 0 or 1 (NaN included), 2 an asymmetric pair, 4 a nonzero diagonal entry, the
// last two judged on the bytes (0: the graph is valid).
extern "C" int mcjax_adjacency_bytes(const double* a, int64_t mats, int64_t n, uint8_t* out, int64_t threads) {
  std::atomic<int> found{0};
  over_threads(mats, threads, [&](int64_t g0, int64_t g1) {
    int bad = 0;
    int64_t nn = n * n;
    const double* __restrict A = a + g0 * nn;
    uint8_t* __restrict O = out + g0 * nn;
    for (int64_t e = 0; e < (g1 - g0) * nn; ++e) {  // values, and the bytes: one flat loop
      double v = A[e];
      bad |= (v == 0.0 || v == 1.0) ? 0 : 1;
      O[e] = v == 1.0;
    }
    for (int64_t g = 0; g < g1 - g0; ++g)  // symmetry and diagonal on the bytes
      for (int64_t i = 0; i < n; ++i) {
        const uint8_t* row = O + g * nn + i * n;
        bad |= row[i] ? 4 : 0;
        for (int64_t j = i + 1; j < n; ++j) bad |= row[j] != O[g * nn + j * n + i] ? 2 : 0;
      }
    found |= bad;
  });
  return found.load();
}

// The handlers' arguments: the data (and, for the modified ICF, the 0/1 graph), then the
// model (x0, P0, F, Q, R) both share; attributes; the estimates and covariances.
template <typename Binding>
auto model_args(Binding b) {
  return std::move(b)
      .template Arg<ffi::Buffer<ffi::F64>>()
      .template Arg<ffi::Buffer<ffi::F64>>()
      .template Arg<ffi::Buffer<ffi::F64>>()
      .template Arg<ffi::Buffer<ffi::F64>>()
      .template Arg<ffi::Buffer<ffi::F64>>();
}

XLA_FFI_DEFINE_HANDLER_SYMBOL(McjaxLocalEkf, LocalImpl,
                              model_args(ffi::Ffi::Bind().Arg<ffi::Buffer<ffi::F64>>().Arg<ffi::Buffer<ffi::F64>>())
                                  .Attr<int64_t>("threads")
                                  .Ret<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>());

XLA_FFI_DEFINE_HANDLER_SYMBOL(McjaxModifiedIcf, IcfImpl,
                              model_args(ffi::Ffi::Bind()
                                             .Arg<ffi::Buffer<ffi::F64>>()
                                             .Arg<ffi::Buffer<ffi::F64>>()
                                             .Arg<ffi::Buffer<ffi::U8>>())
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("steps")
                                  .Attr<int64_t>("weights")
                                  .Attr<bool>("component")
                                  .Ret<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>());
