// The energy terms' parameter derivatives as local blocks (energy_term.h), and the three sinks
// that turn them into vector–Jacobian products, Jacobian–vector products and dense Jacobians.
//
// A term with parameter derivatives writes one template
//
//   template <class Sink> void parameterBlocks(const TermContext& c, Sink& sink) const;
//
// that asks sink.wants(p) (is group p asked for?) and hands over ∂g/∂p in pieces, each ADDED:
//   sink.add(p, dof, param, M)         M (rows × cols) at DoF rows [dof, dof + rows) and
//                                      parameter columns [param, param + cols);
//   sink.add(p, dof, param, A, B)      the same for M = A B, kept factored: a vector–Jacobian
//                                      product is then Bᵀ (Aᵀ λ), a rank-one block u vᵀ costs
//                                      rows + cols, not rows · cols;
//   sink.add(p, point, param, A, B)    a skinned surface point's node-space block A B (3 × cols)
//                                      of ∂g_x/∂p, reaching every bone a the point moves with
//                                      as C_a A B (SkinnedPoint).
// DoFs are the simulable's own (no scene offset): bone b's translation rows start at
// translationRow(b), its rotation rows at rotationRow(b). Pieces may overlap; they are summed.
#pragma once

#include <Eigen/Core>
#include <utility>
#include <vector>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/rotation.h"
#include "flsh/core/types.h"
#include "flsh/sim/energy_term.h"

namespace flsh::detail {

/// First DoF row of bone b's translation and rotation increments.
inline int translationRow(int b) { return 6 * b; }
inline int rotationRow(int b) { return 6 * b + 3; }

/// A point on the skinned surface, x = Σ_a w_a (y_a + t_a) with lever arms y_a = R_a (X − J_a):
/// ∂x/∂q_a = w_a [I, −[y_a]×], so a node-space row block of the gradient reaches bone a's six
/// rows through C_a = (∂x/∂q_a)ᵀ = w_a [I; [y_a]×], and the point's cotangent of λ is
/// μ = Σ_a C_aᵀ λ_a = Σ_a w_a (λt_a − [y_a]× λω_a). A soft skeleton's node also moves with soft
/// DoFs: `soft` lists (first DoF s, S = ∂x/∂q[s, s + 3)), 3 × 3 each (FEM: its own u_j, S = M_j;
/// ROM: every handle of its basis row, S = φ_h M_j); they reach rows s through Sᵀ and add S λ_s
/// to μ. A ROM with modes adds ∂x/∂z_modes = M_j Ψ_j (3 × r) as `modes` (Ψ_j's rows, 3 × r
/// row-major; null without), `blend` (M_j) and `modal_dof` (the first modal DoF), applied as
/// M_j (Ψ_j λ_m) and Ψ_jᵀ (M_jᵀ f) without forming the product. Empty for the articulated
/// skeleton.
struct SkinnedPoint {
  int id = -1;  ///< unique within one parameterBlocks call (a sink may keep the last μ)
  int count = 0;
  int bone[kNumJoints];
  double weight[kNumJoints];
  Vec3 lever[kNumJoints];
  std::vector<std::pair<int, Mat3>> soft;
  const double* modes = nullptr;
  int num_modes = 0, modal_dof = 0;
  Mat3 blend = Mat3::Zero();
  /// The point's cotangent μ = J λ for the λ of the sink it is handed to, when the term that
  /// hands it over knows it (SoftKinematics::massCotangents); null: the sink forms it.
  const Vec3* known_cotangent = nullptr;

  /// Ψ_j as a 3 × r map (valid when modes is not null).
  Eigen::Map<const Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>> modeRows() const {
    return {modes, 3, num_modes};
  }
  Vec3 cotangent(const VecX& lambda) const {
    Vec3 mu = Vec3::Zero();
    for (int a = 0; a < count; ++a)
      mu += weight[a] * (lambda.segment<3>(translationRow(bone[a])) -
                         lever[a].cross(lambda.segment<3>(rotationRow(bone[a]))));
    for (const auto& [s, S] : soft) mu += S * lambda.segment<3>(s);
    if (modes) mu += blend * (modeRows() * lambda.segment(modal_dof, num_modes));
    return mu;
  }
  /// g += Σ_a C_a f (+ Sᵀ f at the soft rows): the point's node-space force f on the DoFs.
  void addForce(const Vec3& f, VecX& g) const {
    for (int k = 0; k < count; ++k) {
      g.segment<3>(translationRow(bone[k])) += weight[k] * f;
      g.segment<3>(rotationRow(bone[k])) += weight[k] * lever[k].cross(f);
    }
    for (const auto& [s, S] : soft) g.segment<3>(s) += S.transpose() * f;
    if (modes)
      g.segment(modal_dof, num_modes).noalias() += modeRows().transpose() * (blend.transpose() * f);
  }
};

/// λᵀ ∂g/∂p: out[p][param …] += Mᵀ λ[dof …].
class VectorJacobianSink {
 public:
  VectorJacobianSink(const VecX& lambda, ParameterProducts<VecX>& out)
      : lambda_(lambda), out_(out) {}
  /// The λ of the products (a term that knows its points' J λ for it hands them over).
  const VecX* lambda() const { return &lambda_; }
  bool wants(SimParameter p) const { return out_.wants(p); }
  template <class M>
  void add(SimParameter p, int dof, int param, const Eigen::MatrixBase<M>& m) {
    target<M::ColsAtCompileTime>(p, param, m.cols()).noalias() +=
        m.transpose() * lambda_.template segment<M::RowsAtCompileTime>(dof, m.rows());
  }
  template <class A, class B>
  void add(SimParameter p, int dof, int param, const Eigen::MatrixBase<A>& a,
           const Eigen::MatrixBase<B>& b) {
    const Eigen::Matrix<double, A::ColsAtCompileTime, 1> inner =
        a.transpose() * lambda_.template segment<A::RowsAtCompileTime>(dof, a.rows());
    target<B::ColsAtCompileTime>(p, param, b.cols()).noalias() += b.transpose() * inner;
  }
  template <class A, class B>
  void add(SimParameter p, const SkinnedPoint& point, int param, const Eigen::MatrixBase<A>& a,
           const Eigen::MatrixBase<B>& b) {
    if (point.known_cotangent) {
      mu_ = *point.known_cotangent;
      mu_id_ = -1;
    } else if (point.id != mu_id_) {
      mu_ = point.cotangent(lambda_);
      mu_id_ = point.id;
    }
    const Eigen::Matrix<double, A::ColsAtCompileTime, 1> inner = a.transpose() * mu_;
    target<B::ColsAtCompileTime>(p, param, b.cols()).noalias() += b.transpose() * inner;
  }

 private:
  template <int Cols>
  auto target(SimParameter p, int param, Eigen::Index cols) {
    return out_[p].template segment<Cols>(param, cols);
  }
  const VecX& lambda_;
  ParameterProducts<VecX>& out_;
  int mu_id_ = -1;
  Vec3 mu_;
};

/// ∂g/∂p ṗ for several directions: out[d][dof …] += M ṗ_d[param …].
class JacobianVectorSink {
 public:
  JacobianVectorSink(const std::vector<ParameterDirection>& directions, std::vector<VecX>& out)
      : directions_(directions), out_(out) {}
  const VecX* lambda() const { return nullptr; }  ///< no λ: tangents
  bool wants(SimParameter p) const {
    for (const ParameterDirection& d : directions_)
      if (given(d, p)) return true;
    return false;
  }
  template <class M>
  void add(SimParameter p, int dof, int param, const Eigen::MatrixBase<M>& m) {
    for (size_t d = 0; d < directions_.size(); ++d)
      if (given(directions_[d], p))
        out_[d].template segment<M::RowsAtCompileTime>(dof, m.rows()).noalias() +=
            m * source<M::ColsAtCompileTime>(d, p, param, m.cols());
  }
  template <class A, class B>
  void add(SimParameter p, int dof, int param, const Eigen::MatrixBase<A>& a,
           const Eigen::MatrixBase<B>& b) {
    for (size_t d = 0; d < directions_.size(); ++d) {
      if (!given(directions_[d], p)) continue;
      const Eigen::Matrix<double, A::ColsAtCompileTime, 1> inner =
          b * source<B::ColsAtCompileTime>(d, p, param, b.cols());
      out_[d].template segment<A::RowsAtCompileTime>(dof, a.rows()).noalias() += a * inner;
    }
  }
  template <class A, class B>
  void add(SimParameter p, const SkinnedPoint& point, int param, const Eigen::MatrixBase<A>& a,
           const Eigen::MatrixBase<B>& b) {
    for (size_t d = 0; d < directions_.size(); ++d) {
      if (!given(directions_[d], p)) continue;
      const Vec3 dx = a * (b * source<B::ColsAtCompileTime>(d, p, param, b.cols()));
      point.addForce(dx, out_[d]);
    }
  }

 private:
  static bool given(const ParameterDirection& d, SimParameter p) {
    const VecX* v = d[size_t(p)];
    return v && v->size() > 0;
  }
  template <int Cols>
  auto source(size_t d, SimParameter p, int param, Eigen::Index cols) const {
    return directions_[d][size_t(p)]->template segment<Cols>(param, cols);
  }
  const std::vector<ParameterDirection>& directions_;
  std::vector<VecX>& out_;
};

/// ∂g/∂p itself: out[p] (numDofs × parameterSize(p)) at the block's place += M.
class JacobianSink {
 public:
  explicit JacobianSink(ParameterProducts<MatX>& out) : out_(out) {}
  const VecX* lambda() const { return nullptr; }  ///< no λ: Jacobians
  bool wants(SimParameter p) const { return out_.wants(p); }
  template <class M>
  void add(SimParameter p, int dof, int param, const Eigen::MatrixBase<M>& m) {
    out_[p].template block<M::RowsAtCompileTime, M::ColsAtCompileTime>(dof, param, m.rows(),
                                                                       m.cols()) += m;
  }
  template <class A, class B>
  void add(SimParameter p, int dof, int param, const Eigen::MatrixBase<A>& a,
           const Eigen::MatrixBase<B>& b) {
    add(p, dof, param, a * b);
  }
  template <class A, class B>
  void add(SimParameter p, const SkinnedPoint& point, int param, const Eigen::MatrixBase<A>& a,
           const Eigen::MatrixBase<B>& b) {
    const Eigen::Matrix<double, 3, B::ColsAtCompileTime> x = a * b;
    for (int k = 0; k < point.count; ++k) {
      const int bone = point.bone[k];
      add(p, translationRow(bone), param, point.weight[k] * x);
      add(p, rotationRow(bone), param, point.weight[k] * skew(point.lever[k]) * x);
    }
    for (const auto& [s, S] : point.soft) add(p, s, param, S.transpose() * x);
    if (point.modes) {
      const Eigen::Matrix<double, 3, B::ColsAtCompileTime> Mx = point.blend.transpose() * x;
      add(p, point.modal_dof, param, point.modeRows().transpose() * Mx);
    }
  }

 private:
  ParameterProducts<MatX>& out_;
};

/// Subtree of every bone (itself included, ascending), from the parent list (root −1).
std::vector<std::vector<int>> boneSubtrees(const std::vector<int>& parents);

double totalMass(const std::vector<BoneInertia>& inertia);

}  // namespace flsh::detail

namespace flsh {

template <class Derived>
void TermWithParameterBlocks<Derived>::addParameterProducts(const TermContext& c,
                                                            const VecX& lambda,
                                                            ParameterProducts<VecX>& out) const {
  detail::VectorJacobianSink sink(lambda, out);
  static_cast<const Derived&>(*this).parameterBlocks(c, sink);
}

template <class Derived>
void TermWithParameterBlocks<Derived>::addParameterTangents(
    const TermContext& c, const std::vector<ParameterDirection>& directions,
    std::vector<VecX>& out) const {
  detail::JacobianVectorSink sink(directions, out);
  static_cast<const Derived&>(*this).parameterBlocks(c, sink);
}

template <class Derived>
void TermWithParameterBlocks<Derived>::addParameterJacobians(const TermContext& c,
                                                             ParameterProducts<MatX>& out) const {
  detail::JacobianSink sink(out);
  static_cast<const Derived&>(*this).parameterBlocks(c, sink);
}

}  // namespace flsh
