// Optimized cubature: greedy selection + Lawson–Hanson NNLS (cubature.h).
#include "flsh/volume/cubature.h"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <string>
#include <vector>

#include "flsh/core/error.h"

namespace flsh {

namespace {

/// A·1, summed column by column in index order: the same operations as a cubature with every
/// element at weight 1, so that one reproduces it bit for bit.
VecX exactIntegral(const MatX& A) {
  VecX b = VecX::Zero(A.rows());
  for (int e = 0; e < A.cols(); ++e) b += 1.0 * A.col(e);
  return b;
}

std::string shape2(long rows, long cols) { return shapeString({rows, cols}); }

void checkMatrix(const MatX& A, const char* who) {
  if (A.rows() == 0 || A.cols() == 0)
    throw InputError(std::string(who) + ": A has shape " + shape2(A.rows(), A.cols()) +
                     ", expected at least one sample (row) and one element (column)");
  if (!A.allFinite()) throw InputError(std::string(who) + ": A contains NaN or Inf");
}

/// Solves G_PP y = c_P (G symmetric positive semi-definite); the minimum-norm solution when G_PP
/// is singular (repeated or zero columns).
/// G_PP: the rows and columns `passive` of G.
MatX passiveBlock(const MatX& G, const std::vector<int>& passive) {
  const int p = int(passive.size());
  MatX Gp(p, p);
  for (int a = 0; a < p; ++a)
    for (int b = 0; b < p; ++b) Gp(a, b) = G(passive[size_t(a)], passive[size_t(b)]);
  return Gp;
}

VecX solvePassive(const MatX& G, const VecX& c, const std::vector<int>& passive) {
  const int p = int(passive.size());
  const MatX Gp = passiveBlock(G, passive);
  VecX cp(p);
  for (int a = 0; a < p; ++a) cp[a] = c[passive[a]];
  const Eigen::LLT<MatX> llt(Gp);
  if (llt.info() == Eigen::Success) {
    VecX y = llt.solve(cp);
    if (y.allFinite()) return y;
  }
  return Gp.completeOrthogonalDecomposition().solve(cp);
}

/// The Cholesky factor L Lᵀ = G_PP of a passive set P kept between Lawson–Hanson's solves:
/// an element entering appends one row to L (O(p²) instead of a new O(p³) factorization, the
/// selection's main cost at hundreds of elements); any other change refactors.
class PassiveFactor {
 public:
  /// y = G_PP⁻¹ c_P, y[a] for passive[a] (ascending indices); the minimum-norm solution (as
  /// solvePassive) when G_PP is singular.
  VecX solve(const MatX& G, const VecX& c, const std::vector<int>& passive) {
    const int p = int(passive.size());
    if (!(valid_ && (p == size_ || p == size_ + 1) && covers(passive))) refactor(G, passive);
    if (valid_ && p == size_ + 1) append(G, passive);
    if (!valid_) return solvePassive(G, c, passive);
    VecX z(p);  // c in the factor's order
    for (int a = 0; a < p; ++a) z[a] = c[order_[size_t(a)]];
    const auto L = L_.topLeftCorner(p, p).triangularView<Eigen::Lower>();
    L.solveInPlace(z);
    L.transpose().solveInPlace(z);
    if (!z.allFinite()) {
      valid_ = false;
      return solvePassive(G, c, passive);
    }
    VecX y(p);
    for (int a = 0; a < p; ++a) y[a] = z[position_[size_t(passive[size_t(a)])]];
    return y;
  }

 private:
  // Whether every element of the factor is in `passive`.
  bool covers(const std::vector<int>& passive) const {
    int found = 0;
    for (int i : passive) found += position_.size() > size_t(i) && position_[size_t(i)] >= 0;
    return found == size_;
  }
  void refactor(const MatX& G, const std::vector<int>& passive) {
    const int p = int(passive.size());
    position_.assign(size_t(G.rows()), -1);
    order_.assign(passive.begin(), passive.end());
    const Eigen::LLT<MatX> llt(passiveBlock(G, passive));
    valid_ = llt.info() == Eigen::Success;
    size_ = valid_ ? p : 0;
    if (!valid_) {
      order_.clear();
      return;
    }
    L_ = llt.matrixL();
    for (int a = 0; a < p; ++a) position_[size_t(order_[size_t(a)])] = a;
  }
  // Appends the one element of `passive` not in the factor: L's new row l = L⁻¹ g, diagonal
  // √(G_ii − lᵀl), or the factor is given up when that is not clearly positive.
  void append(const MatX& G, const std::vector<int>& passive) {
    int fresh = -1;
    for (int i : passive)
      if (position_[size_t(i)] < 0) fresh = i;
    const int p = size_;
    VecX g(p);
    for (int a = 0; a < p; ++a) g[a] = G(order_[size_t(a)], fresh);
    L_.topLeftCorner(p, p).triangularView<Eigen::Lower>().solveInPlace(g);
    const double d2 = G(fresh, fresh) - g.squaredNorm();
    if (!(d2 > 1e-12 * std::abs(G(fresh, fresh))) || !g.allFinite()) {
      valid_ = false;
      size_ = 0;
      return;
    }
    if (L_.rows() < p + 1) {
      MatX grown = MatX::Zero(std::max(2 * p, p + 1), std::max(2 * p, p + 1));
      grown.topLeftCorner(p, p) = L_.topLeftCorner(p, p);
      L_ = std::move(grown);
    }
    L_.row(p).head(p) = g.transpose();
    L_(p, p) = std::sqrt(d2);
    order_.push_back(fresh);
    position_[size_t(fresh)] = p;
    size_ = p + 1;
  }

  bool valid_ = false;
  int size_ = 0;               // elements in the factor
  std::vector<int> order_;     // the factor's elements, in its order
  std::vector<int> position_;  // element → row of L, −1 when not in the factor
  MatX L_;                     // lower triangular, the top-left size_ square in use
};

/// Lawson–Hanson on the normal equations: min ½ xᵀGx − cᵀx, x ≥ 0, warm-started from x (any
/// vector; its positive entries are the first passive set). Returns x ≥ 0.
VecX nnlsGram(const MatX& G, const VecX& c, VecX x) {
  PassiveFactor factor;
  const int n = int(c.size());
  x = x.cwiseMax(0.0);
  // Gradient entries below this count as zero: rounding of G x − c relative to its terms.
  const double scale = std::max(c.cwiseAbs().maxCoeff(), G.diagonal().cwiseAbs().maxCoeff());
  const double tolerance = 1e-12 * std::max(scale, 1e-300) * std::max(1, n);
  std::vector<char> in_passive(n, 0);
  for (int i = 0; i < n; ++i) in_passive[i] = x[i] > 0;
  std::vector<char> refused(n, 0);  // entered but could not move: rounding, not descent
  const int max_iterations = 3 * n + 30;
  bool first = true;
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    int entering = -1;
    if (!first) {
      const VecX descent = c - G * x;  // minus the gradient
      double best = tolerance;
      for (int i = 0; i < n; ++i)
        if (!in_passive[i] && !refused[i] && descent[i] > best) {
          best = descent[i];
          entering = i;
        }
      if (entering < 0) break;
      in_passive[entering] = 1;
    }
    first = false;
    // Inner loop: the unconstrained minimizer on the passive set, stepping back to the first
    // entry that would turn negative until it is feasible.
    for (int inner = 0; inner <= n; ++inner) {
      std::vector<int> passive;
      for (int i = 0; i < n; ++i)
        if (in_passive[i]) passive.push_back(i);
      if (passive.empty()) break;
      const VecX y = factor.solve(G, c, passive);
      double alpha = 1;
      int blocking = -1;
      for (int a = 0; a < int(passive.size()); ++a) {
        const int i = passive[a];
        if (y[a] <= 0) {
          const double step = x[i] / (x[i] - y[a]);
          if (step < alpha) {
            alpha = step;
            blocking = i;
          }
        }
      }
      if (blocking < 0) {
        for (int a = 0; a < int(passive.size()); ++a) x[passive[a]] = y[a];
        break;
      }
      if (blocking == entering && x[entering] == 0) {
        // The entering element cannot move: its gradient was rounding noise.
        in_passive[entering] = 0;
        refused[entering] = 1;
        break;
      }
      for (int a = 0; a < int(passive.size()); ++a) {
        const int i = passive[a];
        x[i] += alpha * (y[a] - x[i]);
        if (i == blocking || x[i] <= 0) {
          x[i] = 0;
          in_passive[i] = 0;
        }
      }
    }
    // An element refused earlier may move once the passive set has changed.
    if (entering >= 0 && in_passive[entering]) std::fill(refused.begin(), refused.end(), 0);
  }
  return x;
}

}  // namespace

VecX nonNegativeLeastSquares(const MatX& A, const VecX& b) {
  checkMatrix(A, "nonNegativeLeastSquares");
  if (b.size() != A.rows())
    throw InputError("nonNegativeLeastSquares: b has " + std::to_string(b.size()) +
                     " entries, expected " + std::to_string(A.rows()) + " (rows of A)");
  if (!b.allFinite()) throw InputError("nonNegativeLeastSquares: b contains NaN or Inf");
  const MatX G = A.transpose() * A;
  const VecX c = A.transpose() * b;
  return nnlsGram(G, c, VecX::Zero(A.cols()));
}

double cubatureRelativeError(const MatX& A, const VecXi& elements, const VecX& weights) {
  const char* who = "cubatureRelativeError";
  checkMatrix(A, who);
  if (elements.size() != weights.size())
    throw InputError(std::string(who) + ": " + std::to_string(elements.size()) + " elements but " +
                     std::to_string(weights.size()) + " weights, expected the same number");
  if (!weights.allFinite()) throw InputError(std::string(who) + ": weights contain NaN or Inf");
  const VecX b = exactIntegral(A);
  const double norm = b.norm();
  if (!(norm > 0)) throw InputError(std::string(who) + ": A·1 is zero, expected a non-zero target");
  VecX approximation = VecX::Zero(A.rows());
  for (int k = 0; k < elements.size(); ++k) {
    if (elements[k] < 0 || elements[k] >= A.cols())
      throw InputError(std::string(who) + ": elements[" + std::to_string(k) +
                       "] = " + std::to_string(elements[k]) + ", expected 0.." +
                       std::to_string(A.cols() - 1));
    approximation += weights[k] * A.col(elements[k]);
  }
  return (approximation - b).norm() / norm;
}

Cubature exactCubature(int elements) {
  Cubature every;
  every.elements = VecXi::LinSpaced(elements, 0, elements - 1);
  every.weights = VecX::Ones(elements);
  return every;
}

namespace {
constexpr int kCorrelationBlock = 1024;  // columns per task of selectCubature's correlation
// Smallest cosine between a candidate and the residual: above the rounding of a single-precision
// correlation over thousands of samples (~1e-7 · √samples relative).
constexpr double kSingleCosine = 1e-5;
}  // namespace

Cubature selectCubature(const MatX& A, const CubatureOptions& options) {
  const char* who = "selectCubature";
  checkMatrix(A, who);
  if (options.count < 1)
    throw InputError(std::string(who) + ": options.count = " + std::to_string(options.count) +
                     ", expected ≥ 1");
  if (!(options.tolerance >= 0))
    throw InputError(std::string(who) + ": options.tolerance = " +
                     std::to_string(options.tolerance) + ", expected ≥ 0");
  if (options.points_per_round < 1)
    throw InputError(std::string(who) + ": options.points_per_round = " +
                     std::to_string(options.points_per_round) + ", expected ≥ 1");
  const int E = int(A.cols());
  const VecX b = exactIntegral(A);
  const double b_norm = b.norm();
  if (!(b_norm > 0))
    throw InputError(std::string(who) + ": the target A·1 is zero, expected a non-zero target");
  const VecX column_norms = A.colwise().norm().transpose();
  // The rounds' correlation reads A in single precision, made once: each round's pass over the
  // whole of A is memory-bound (at 2000 samples × 35 000 tets, 550 MB in double), and halving
  // its bytes halves it. Only the ranking of the candidates sees the rounding (~1e-7 of a
  // correlation); G, c, the weights and the residual stay in double.
  const Eigen::MatrixXf A_single = A.cast<float>();

  std::vector<int> selected;  // in selection order
  std::vector<char> is_selected(E, 0);
  MatX G(0, 0);  // A_Sᵀ A_S
  VecX c(0);     // A_Sᵀ b
  VecX w(0);
  VecX residual = b;
  Cubature out;
  out.training_error = 1;
  const int count = std::min(options.count, E);
  const int max_rounds = 4 * count + 10;
  while (int(selected.size()) < count && out.training_error > options.tolerance &&
         out.rounds < max_rounds) {
    // Correlation of every unselected element with the residual (normalized columns): the
    // round's main cost (A is read whole), on every thread in fixed blocks of columns (the same
    // values for any thread count).
    Eigen::VectorXf correlation(E);
    const Eigen::VectorXf residual_single = residual.cast<float>();
    const int blocks = (E + kCorrelationBlock - 1) / kCorrelationBlock;
#pragma omp parallel for schedule(static)
    for (int k = 0; k < blocks; ++k) {
      const int first = k * kCorrelationBlock, n = std::min(kCorrelationBlock, E - first);
      correlation.segment(first, n).noalias() =
          A_single.middleCols(first, n).transpose() * residual_single;
    }
    // A candidate's cosine with the residual must be clear of the single-precision rounding.
    std::vector<int> candidates;
    const double residual_norm = residual.norm();
    for (int e = 0; e < E; ++e)
      if (!is_selected[e] && column_norms[e] > 0 &&
          correlation[e] > kSingleCosine * column_norms[e] * residual_norm)
        candidates.push_back(e);
    if (candidates.empty()) break;  // no element can lower the error
    const int take = std::min<int>(
        {options.points_per_round, int(candidates.size()), count - int(selected.size())});
    std::partial_sort(candidates.begin(), candidates.begin() + take, candidates.end(),
                      [&](int a, int b2) {
                        const double sa = double(correlation[a]) / column_norms[a];
                        const double sb = double(correlation[b2]) / column_norms[b2];
                        return sa != sb ? sa > sb : a < b2;
                      });
    ++out.rounds;
    const int old_size = int(selected.size());
    const int new_size = old_size + take;
    G.conservativeResize(new_size, new_size);
    c.conservativeResize(new_size);
    w.conservativeResize(new_size);
    for (int k = 0; k < take; ++k) {
      const int e = candidates[k];
      selected.push_back(e);
      is_selected[e] = 1;
      w[old_size + k] = 0;
      c[old_size + k] = A.col(e).dot(b);
    }
    // The new columns of G: each selected column read once against the round's new ones
    // (gathered), not once per new column; every entry a fixed dot product, whatever the threads.
    MatX fresh(A.rows(), take);
    for (int k = 0; k < take; ++k) fresh.col(k) = A.col(selected[old_size + k]);
#pragma omp parallel for schedule(static)
    for (int j = 0; j < new_size; ++j)
      G.row(j).segment(old_size, take).noalias() = A.col(selected[j]).transpose() * fresh;
    for (int k = old_size; k < new_size; ++k)
      for (int j = 0; j < k; ++j) G(k, j) = G(j, k);
    w = nnlsGram(G, c, w);
    // Elements the fit dropped to weight 0 leave the set (and may come back later).
    std::vector<int> keep;
    for (int k = 0; k < new_size; ++k)
      if (w[k] > 0)
        keep.push_back(k);
      else
        is_selected[selected[k]] = 0;
    if (int(keep.size()) < new_size) {
      std::vector<int> kept_elements;
      MatX G2(keep.size(), keep.size());
      VecX c2(keep.size()), w2(keep.size());
      for (int a = 0; a < int(keep.size()); ++a) {
        kept_elements.push_back(selected[keep[a]]);
        c2[a] = c[keep[a]];
        w2[a] = w[keep[a]];
        for (int b2 = 0; b2 < int(keep.size()); ++b2) G2(a, b2) = G(keep[a], keep[b2]);
      }
      selected = kept_elements;
      G = G2;
      c = c2;
      w = w2;
    }
    residual = b;
    for (int k = 0; k < int(selected.size()); ++k) residual -= w[k] * A.col(selected[k]);
    const double previous_error = out.training_error;
    out.training_error = residual.norm() / b_norm;
    // A round that does not lower the error means the residual is rounding noise: stop.
    if (!(out.training_error < previous_error * (1 - 1e-9))) break;
  }
  std::vector<int> order(selected.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b2) { return selected[a] < selected[b2]; });
  out.elements.resize(int(selected.size()));
  out.weights.resize(int(selected.size()));
  for (int k = 0; k < int(order.size()); ++k) {
    out.elements[k] = selected[order[k]];
    out.weights[k] = w[order[k]];
  }
  return out;
}

}  // namespace flsh
