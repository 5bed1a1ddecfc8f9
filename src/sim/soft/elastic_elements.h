// The tets the elastic energy of a soft skeleton sums over, and the interface both elastic
// terms share. Elements: every tet with a soft-tissue node (tets whose four nodes are bone
// nodes never deform), or the ROM's elastic cubature's sample tets with their weights; each
// with its rest shape gradients and its material point. Private to Simulable.
#pragma once

#include <vector>

#include "flsh/core/hessian_blocks.h"
#include "flsh/energy/fem_material.h"
#include "flsh/sim/energy_term.h"
#include "sim/soft/node_term.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

struct ElasticElements {
  MatX4i tets;   ///< nodes of each element
  VecX weights;  ///< 1, or the elastic cubature's weights
  std::vector<TetElementRest> rest;
  std::vector<FemMaterialPoint> materials;
  int size() const { return int(tets.rows()); }
};

/// The avatar's elastic elements (volume/elastic_tets.h: the tets with a soft-tissue node, at
/// the avatar's rest nodes X̄(β)), all of them or the ROM's elastic cubature's.
ElasticElements elasticElements(const SoftAvatar& avatar);

/// The elastic energy of a soft skeleton (FEM: fem_elasticity_term.h; ROM:
/// reduced_elasticity_term.h).
class ElasticityTerm : public NodeTerm<1> {
 public:
  const char* name() const override { return "elasticity"; }
  double evaluate(const TermContext&, VecX* g, int offset) const override {
    return evaluate(g, nullptr, offset, true);
  }
  /// FEM: the node-pair blocks as fixed blocks; ROM: value list 1.
  void addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                        std::vector<FixedHessianBlocks>* blocks, int offset,
                        bool psd) const override;
  /// At the prepared state: the energy, its gradient ADDED into g, its Hessian (FEM: triplets
  /// appended to H or, with `blocks`, returned at fixed positions; ROM: into value list 1).
  virtual double evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                          FixedHessianBlocks* blocks = nullptr) const = 0;

 protected:
  explicit ElasticityTerm(const SoftKinematics& kinematics) : NodeTerm(kinematics) {}
};

}  // namespace flsh::detail
