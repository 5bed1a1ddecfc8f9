// The sinks of the node terms' unposed-position derivatives (node_offset_derivatives.h) and the
// products built from them. A term's nodeOffsetBlocks hands over ∂g/∂Y_j in pieces, each ADDED:
//   sink.add(point, j, B)         J_jᵀ B d_j: a 3 × 3 node-space block reaching the DoFs through
//                                 node j's SkinnedPoint (term_blocks.h; id set by the term);
//   sink.addRotation(b, j, M)     M d_j at bone b's rotation rows.
// For a term E(x, x̂) with node force f_j = ∂E/∂x_j these are B = K_j M_j (K_j the exact node
// Hessian; inertia: minus its prediction's share) and, per influence, M = −w_jb [f_j]× R_b
// (the lever arm r_jb = R_b (Y_j − J_b) of J_jᵀ's rotation rows turns with Y_j).
#pragma once

#include "sim/soft/node_offset_derivatives.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

/// (∂g/∂Y)ᵀ λ: out.row(j) += (Bᵀ J_j λ)ᵀ and (Mᵀ λ_ω,b)ᵀ.
class NodeOffsetCotangentSink {
 public:
  NodeOffsetCotangentSink(const VecX& lambda, MatX3& out) : lambda_(lambda), out_(out) {}
  /// The λ of the products (see VectorJacobianSink::lambda).
  const VecX* lambda() const { return &lambda_; }
  void add(const SkinnedPoint& point, int j, const Mat3& B) {
    if (point.known_cotangent) {
      mu_ = *point.known_cotangent;
      mu_id_ = -1;
    } else if (point.id != mu_id_) {
      mu_ = point.cotangent(lambda_);
      mu_id_ = point.id;
    }
    out_.row(j) += (B.transpose() * mu_).transpose();
  }
  void addRotation(int b, int j, const Mat3& M) {
    out_.row(j) += (M.transpose() * lambda_.segment<3>(rotationRow(b))).transpose();
  }

 private:
  const VecX& lambda_;
  MatX3& out_;
  int mu_id_ = -1;
  Vec3 mu_;
};

/// ∂g/∂Y dY: J_jᵀ B dY_j and M dY_j at the rotation rows, into out.
class NodeOffsetTangentSink {
 public:
  NodeOffsetTangentSink(const MatX3& dY, VecX& out) : dY_(dY), out_(out) {}
  const VecX* lambda() const { return nullptr; }  ///< no λ: tangents
  void add(const SkinnedPoint& point, int j, const Mat3& B) {
    point.addForce(B * dY_.row(j).transpose(), out_);
  }
  void addRotation(int b, int j, const Mat3& M) {
    out_.segment<3>(rotationRow(b)) += M * dY_.row(j).transpose();
  }

 private:
  const MatX3& dY_;
  VecX& out_;
};

template <class Derived>
void WithNodeOffsetBlocks<Derived>::addNodeOffsetProducts(const TermContext& c, const VecX& lambda,
                                                          MatX3& out) const {
  NodeOffsetCotangentSink sink(lambda, out);
  static_cast<const Derived&>(*this).nodeOffsetBlocks(c, sink);
}

template <class Derived>
void WithNodeOffsetBlocks<Derived>::addNodeOffsetTangent(const TermContext& c, const MatX3& dY,
                                                         VecX& out) const {
  NodeOffsetTangentSink sink(dY, out);
  static_cast<const Derived&>(*this).nodeOffsetBlocks(c, sink);
}

}  // namespace flsh::detail
