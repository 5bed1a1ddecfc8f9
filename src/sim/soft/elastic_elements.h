// The tets the elastic energy of a soft skeleton sums over, and the interface both elastic
// terms share. Elements: every tet with a soft-tissue node (tets whose four nodes are bone
// nodes never deform), or the ROM's elastic cubature's sample tets with their weights; each
// with its rest shape gradients and its material point. Private to Simulable.
#pragma once

#include <functional>
#include <vector>

#include "flsh/core/hessian_blocks.h"
#include "flsh/energy/fem_material.h"
#include "flsh/sim/energy_term.h"
#include "flsh/volume/reduced_data.h"
#include "sim/soft/material_chain.h"
#include "sim/soft/nodal_element_derivatives.h"
#include "sim/soft/node_term.h"
#include "sim/soft/shape_chain.h"
#include "sim/soft/soft_kinematics.h"

namespace flsh::detail {

struct ElasticElements {
  std::vector<int> tet;  ///< each element's tet in the avatar's tet mesh
  MatX4i tets;           ///< nodes of each element
  VecX weights;          ///< 1, or the elastic cubature's weights
  std::vector<TetElementRest> rest;
  std::vector<FemMaterialPoint> materials;
  int size() const { return int(tets.rows()); }
};

/// The material map's cotangent (tet_material_map.h) of an element's material-point cotangent
/// (no density: the elastic energy does not read it).
inline TetMaterialCotangent materialCotangent(const FemMaterialDerivative& d) {
  TetMaterialCotangent bar;
  bar.C_world = d.C_world;
  bar.modulus = d.modulus;
  bar.gamma = d.gamma;
  return bar;
}

/// The avatar's elastic elements (volume/elastic_tets.h: the tets with a soft-tissue node, at
/// the avatar's rest nodes X̄(β)), all of them or the ROM's elastic cubature's.
ElasticElements elasticElements(const SoftAvatar& avatar);

/// Element e of a ROM's elastic cubature as nodal_element_derivatives.h takes it: with the
/// rest-stiffness split's floor when `floors` (elementRestFloors) is not empty.
inline SampleElement sampleElement(const ElasticElements& elements, const VecX& floors, int e) {
  return {elements.rest[size_t(e)], elements.materials[size_t(e)], elements.weights[e],
          floors.size() > 0 ? floors[e] : 0.0};
}

/// The floors of the ROM's rest-stiffness split (ReducedData::elastic_floors) of each element
/// (a sample of rom's elastic cubature). InputError when rom has no floor per sample or an
/// element is not a sample.
VecX elementRestFloors(const ReducedData& rom, const ElasticElements& elements);

/// The elastic energy of a soft skeleton (FEM: fem_elasticity_term.h; ROM:
/// reduced_elasticity_term.h with handles, modal_elasticity_term.h with modes).
///
/// Material derivatives (SimParameter::Material, in the coefficient values of MaterialChain):
/// the gradient's product with a direction Λ is, element by element, a function of the
/// element's material point (C_world, μ, γ) whose derivative the elastic law gives
/// (fem_material.h addStressMaterialGradient); the per-tet material map chains it to the
/// coefficients. Each model lists its "material elements" (the FEM's tets; the ROM's sample tets
/// and, with the rest-stiffness split, every elastic tet of ½ zᵀ K z) with their local
/// directions; the vector–Jacobian product is one pass with Λ = λ, the tangents and Jacobians
/// take the element's rows (Λ a unit direction each) from the same function.
class ElasticityTerm : public NodeTerm<1> {
 public:
  const char* name() const override { return "elasticity"; }
  /// The tissue's deformation in the unposed frame: u (FEM) or z (ROM) alone.
  bool dependsOnBones() const override { return false; }
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

  /// The Material group only, in coefficient values (numCoefficients() entries or columns).
  void addParameterProducts(const TermContext& c, const VecX& lambda,
                            ParameterProducts<VecX>& out) const override;
  void addParameterTangents(const TermContext& c, const std::vector<ParameterDirection>& directions,
                            std::vector<VecX>& out) const override;
  void addParameterJacobians(const TermContext& c, ParameterProducts<MatX>& out) const override;
  /// The products of many steps, chained once (a reverse sweep): per step ADDS into row e of
  /// `elements` (numProductElements() × kMaterialPointValues, resized from empty) element e's
  /// material-point cotangent of λᵀ g (C_world's 36 entries column-major, μ, γ) and, for the
  /// ROM with the rest-stiffness split, λ zᵀ into `rest_outer` (3H × 3H, resized from empty).
  /// `shape` (may be null): in the same pass, ADDS into beta_bar the share of λᵀ ∂g/∂β that
  /// needs this step's state: the product elements' rest shapes (the rest of β's share comes
  /// once from addAccumulatedMaterialProducts).
  void accumulateMaterialProducts(const VecX& lambda, MatX& elements, MatX& rest_outer,
                                  const ShapeChain* shape = nullptr,
                                  VecX* beta_bar = nullptr) const;
  /// ADDS into values_bar (coefficient values) the cotangent of such sums: each element's
  /// through the material map, the rest stiffness's with one pass over every elastic tet.
  /// `shape` (may be null): also ADDS into beta_bar β's share of the same sums that does not
  /// need the steps one by one — the tets' areas and volumes through the material map, and for
  /// the ROM the rest shapes of every tet of ½ zᵀ K z (bilinear in λ and z: from Σ λ zᵀ); the
  /// coefficient values' share is the caller's (values_bar through ∂c/∂β).
  void addAccumulatedMaterialProducts(const MatX& elements, const MatX& rest_outer,
                                      VecX& values_bar, const ShapeChain* shape = nullptr,
                                      VecX* beta_bar = nullptr) const;
  static constexpr int kMaterialPointValues = 38;

  // ---- Shape (β): element by element, the rest nodes X̄(β) move Λᵀ g_e through the tet's rest
  // shape (materialElementProducts' X_bar) and its material point through c(β) and the skin
  // fraction's area and volume (the per-tet material map; frames held) ----
  /// ADDS λᵀ ∂g/∂β (K) into beta_bar at the prepared state. (A reverse sweep takes the share
  /// that needs each step's state — the rest shapes of the product elements, the FEM's tets or
  /// the ROM's samples — in accumulateMaterialProducts, the rest once from
  /// addAccumulatedMaterialProducts.)
  void addShapeProducts(const VecX& lambda, const ShapeChain& shape, VecX& beta_bar) const;
  /// ADDS ∂g/∂β dβ into out (numDofs) / ∂g/∂β into J (numDofs × K): the elements' rows.
  void addShapeTangent(const VecX& dbeta, const ShapeChain& shape, VecX& out) const;
  void addShapeJacobian(const ShapeChain& shape, MatX& J) const;

 protected:
  ElasticityTerm(const SoftKinematics& kinematics, const MaterialChain& chain)
      : NodeTerm(kinematics), chain_(chain) {}
  const MaterialChain& materialChain() const { return chain_; }
  /// The material elements (see above), their tets, their local directions' DoFs (entry 3s + k
  /// for direction k of local column s; relative to the simulable's first DoF; −1: none) and the
  /// material cotangent of the gradient's product with local directions Λ (3 × #columns).
  virtual int numMaterialElements() const = 0;
  virtual int materialElementTet(int e) const = 0;
  virtual void materialElementDofs(int e, std::vector<int>& dofs) const = 0;
  /// The element's tet's four nodes.
  virtual Eigen::Vector4i materialElementNodes(int e) const = 0;
  /// Element e's products of Λᵀ g_e, each when asked (non-null): `d` (zero on entry) receives
  /// the material point's cotangent; X_bar (3 × 4, column a: node a) has the cotangent of the
  /// tet's rest node positions, the material point held, ADDED. One call for both shares the
  /// element's state (the ROMs' nodal form, the law at F).
  virtual void materialElementProducts(int e, const Mat3X& Lambda, FemMaterialDerivative* d,
                                       Mat34* X_bar) const = 0;
  FemMaterialDerivative materialElementGradient(int e, const Mat3X& Lambda) const {
    FemMaterialDerivative d;
    materialElementProducts(e, Lambda, &d, nullptr);
    return d;
  }
  /// The leading material elements whose products take λ element by element (the rest: the
  /// ROM's rest stiffness, through addRestOuter and addRestStiffnessProducts).
  virtual int numProductElements() const { return numMaterialElements(); }
  /// ROM with the split: ADDS λ zᵀ over the soft state's coordinates into W (resized from
  /// empty; addSoftStateOuter).
  virtual void addRestOuter(const VecX& lambda, MatX& W) const {}
  /// W += λ_z zᵀ (numSoftDofs square; resized from empty): the soft state's rows of λ and the
  /// current soft state.
  void addSoftStateOuter(const VecX& lambda, MatX& W) const;
  /// ROM with the split: ADDS into values_bar the rest stiffness's share for Σ λ zᵀ = W (one
  /// pass over every elastic tet) and, with `shape`, β's share of the tets' areas, volumes and
  /// rest shapes into beta_bar. Nothing otherwise.
  virtual void addRestStiffnessProducts(const MatX& W, VecX& values_bar,
                                        const ShapeChain* shape = nullptr,
                                        VecX* beta_bar = nullptr) const {}
  /// The rest quadratic's share for both ROMs: for each tet k (`tet[k]` of the mesh, nodes
  /// `mesh_tets`' row, rest shape and C_world) with T_k from form(k, T) (Σ over the steps of
  /// vec(∇λ_u) vec(∇u)ᵀ, 9 × 9, vec column-major; false: the tet does not move), ADDS its C_world's
  /// cotangent V S T Sᵀ (S: voigtLinearStrainMatrix) through the material map into values_bar and,
  /// with `shape`, β's share (the tet's area and volume, its rest shape) into beta_bar. On the
  /// available threads from 1000 tets (per-thread sums added in thread order).
  void addRestFormCotangents(const std::vector<int>& tet, const std::vector<TetElementRest>& rest,
                             const std::vector<Mat6>& C_world, const MatX4i& mesh_tets,
                             const std::function<bool(int, Mat9&)>& form, VecX& values_bar,
                             const ShapeChain* shape, VecX* beta_bar) const;

 private:
  /// Element e's rows ∂g/∂c at its DoFs: row(dof, values) for every local direction with a DoF.
  template <class Row>
  void materialElementRows(int e, std::vector<int>& dofs, VecX& values, Row&& row) const;
  /// visit(dof, unit) for every local direction of element e with a DoF (unit: that direction,
  /// 3 × #columns).
  template <class Visit>
  void forEachLocalUnit(int e, std::vector<int>& dofs, Visit&& visit) const;
  /// Element e's share of ∂(Λᵀ g_e)/∂β: ADDS into beta_bar its rest nodes' and area/volume's
  /// part and into values_bar its coefficient values' cotangent (chained by the caller).
  void addElementShapeCotangent(int e, const Mat3X& Lambda, const ShapeChain& shape, VecX& beta_bar,
                                VecX& values_bar) const;
  /// ∂g/∂β row by row: row(dof, r) with r = ∂g_dof/∂β (K) for every element's local DoF (the
  /// rows of one DoF come in pieces, to be summed).
  template <class Row>
  void shapeRows(const ShapeChain& shape, Row&& row) const;
  const MaterialChain& chain_;
};

/// The ROM's elastic terms (handles: reduced_elasticity_term.h; modes: modal_elasticity_term.h)
/// as SoftTissue's two-thread schedule runs them: elements in ranges, the rest stiffness apart.
class ReducedElasticity {
 public:
  virtual ~ReducedElasticity() = default;
  virtual int numElements() const = 0;
  /// Elements [first, last): energy returned, gradient added into gz (the soft state's entries;
  /// may be null), Hessian blocks summed into `values` (a value list; may be null).
  virtual double elements(int first, int last, double* gz, Mat3* values, bool psd) const = 0;
  /// ½ zᵀ K z of the rest-stiffness split (0 without it), its gradient and Hessian blocks.
  virtual double restStiffness(VecX* g, Mat3* values, int offset) const = 0;
  /// Whether the term has the rest-stiffness split (K the exact rest stiffness of the subspace).
  virtual bool hasRestSplit() const = 0;
  /// Sample tets whose rest-split excess is in its bounded branch at the current state.
  virtual int boundedSamples() const = 0;

 protected:
  /// The term at the prepared state as both evaluate it: the elements' energy, their gradient
  /// ADDED into g (the soft entries, from offset + kin's bone DoFs) and, with `hessian`, their
  /// blocks into kin's value list 1, then the rest stiffness. Energy or gradient alone from
  /// `split_from` elements: the elements in two halves on two threads, the second half's
  /// gradient apart (the Hessian's block sums stay on one thread: Simulable runs them beside
  /// inertia's).
  double evaluateElements(const SoftKinematics& kin, VecX* g, bool hessian, int offset, bool psd,
                          int split_from) const;
};

}  // namespace flsh::detail
