// The third avatar level: ROM handles, bounded biharmonic basis and the two cubatures, with the
// on-disk cache (reduced_data.h).
#include "flsh/volume/reduced_data.h"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <random>
#include <string>
#include <vector>

#include "core/seconds_since.h"
#include "flsh/core/error.h"
#include "flsh/core/sha256.h"
#include "flsh/energy/fem_material.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/volume_fields.h"
#include "volume/reduced_data_file.h"
#include "volume/subspace_tets.h"

namespace flsh {

namespace {

using Clock = std::chrono::steady_clock;
using detail::secondsSince;

// Revision of the rules of this level (handle choice, sample distributions, basis drop
// threshold): bump it when they change so that data cached under older rules are rebuilt.
constexpr int kReducedRules = 7;  // 1: first version; 2: rest-stiffness correction; 3: elastic
                                  // selection to the full count; 4: its positive part; 5: the
                                  // exact rest stiffness instead (the rest-stiffness split);
                                  // 6: rigid-motion rows in the inertial training; 7: their
                                  // error stored (inertial_rigid_error)
// Smallest handle displacement amplitude of an elastic training sample, m (the samples spread
// log-uniformly from here to training_amplitude: nearly linear to Fung-stiffened strains).
constexpr double kSmallestTrainingAmplitude = 1e-3;
// Largest handle displacement of an elastic training sample relative to the soft-tissue
// thickness under the handle (bone nodes below it do not move): a handle on a thin layer (shin,
// skull) moved by the full training_amplitude would shear its tets far beyond any motion the
// simulation sees, and those few tets' Fung energies would dominate every sample (measured on
// the default body: held-out elastic error 0.31 uncapped, 0.055 with this cap).
constexpr double kMaxTrainingShear = 0.5;
// The greedy selection stops once the training error is this small: the inertial energy, a
// quadratic form, is then fitted about as well as the held-out samples can tell (measured on the
// default body: 1e-3 → 172 tets, held-out 0.0024, 1.4 s; 0 → 386 tets, held-out 0.0012, 3.4 s).
constexpr double kInertialTrainingTolerance = 1e-3;
// The elastic selection runs to the requested count: stopping at 1e-3 kept ~290 tets, too few
// to give every handle's directions stiffness with 150 handles (the simulation blew up).
constexpr double kElasticTrainingTolerance = 0.0;
// Held-out samples of a cubature's error estimate: a quarter of the training samples, at least
// kHeldOutSamples and at most twice that. The estimate's spread over seeds is well below its
// value at 100 (default body: elastic 1.26 % on 400 held-out samples, ~1.2–1.4 % on 100; the
// selection does not use them), and a quarter of 2000 training samples would cost a fifth of
// the training for a diagnostic.
constexpr int kHeldOutSamples = 100;
constexpr double kPi = 3.14159265358979323846;
// RMS scales of the random inertial training velocities: bone translation (m/s), bone rotation
// (rad/s) and handle velocity (m/s), about those of brisk human motion.
constexpr double kBoneSpeed = 1.0, kBoneAngularSpeed = 3.0, kHandleSpeed = 0.3;

std::string str(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%g", v);
  return buffer;
}

void checkSettings(const ReducedSettings& s) {
  const std::string fn = "buildReducedData: ReducedSettings::";
  auto atLeastOne = [&](const char* name, int value) {
    if (value < 1) throw InputError(fn + name + " = " + std::to_string(value) + ", expected ≥ 1");
  };
  atLeastOne("num_handles", s.num_handles);
  atLeastOne("elastic_cubature_points", s.elastic_cubature_points);
  atLeastOne("inertial_cubature_points", s.inertial_cubature_points);
  atLeastOne("training_samples", s.training_samples);
  if (!(s.training_amplitude > 0) || !std::isfinite(s.training_amplitude))
    throw InputError(fn + "training_amplitude = " + str(s.training_amplitude) +
                     ", expected finite and > 0 m");
  const BoundedBiharmonicOptions& b = s.basis;
  if (!(b.kkt_tolerance > 0) || !std::isfinite(b.kkt_tolerance))
    throw InputError(fn + "basis.kkt_tolerance = " + str(b.kkt_tolerance) +
                     ", expected finite and > 0");
  atLeastOne("basis.max_iterations", b.max_iterations);
  if (!(b.initial_radius_factor > 0) || !std::isfinite(b.initial_radius_factor))
    throw InputError(fn + "basis.initial_radius_factor = " + str(b.initial_radius_factor) +
                     ", expected finite and > 0");
  if (b.threads < 0)
    throw InputError(fn + "basis.threads = " + std::to_string(b.threads) + ", expected ≥ 0");
  if (!(s.basis_drop_below >= 0 && s.basis_drop_below <= 0.01))
    throw InputError(fn + "basis_drop_below = " + str(s.basis_drop_below) +
                     ", expected in [0, 0.01]");
}

// Everything the level depends on. basis.threads is left out: the weights do not depend on the
// thread count (computeBoundedBiharmonicWeights is deterministic across schedules).
std::string reducedKey(const VolumetricData& data, const ReducedSettings& s, bool elastic,
                       bool inertial) {
  Sha256 h;
  h.update("flsh reduced data");
  const int version = AvatarCache::kFormatVersion;
  h.updateField("version", &version, sizeof(version));
  const int rules = kReducedRules;
  h.updateField("reduced rules", &rules, sizeof(rules));
  h.updateField("data key", data.key.data(), data.key.size());
  h.updateField("num_handles", &s.num_handles, sizeof(s.num_handles));
  h.updateField("elastic_cubature_points", &s.elastic_cubature_points,
                sizeof(s.elastic_cubature_points));
  h.updateField("inertial_cubature_points", &s.inertial_cubature_points,
                sizeof(s.inertial_cubature_points));
  h.updateField("training_samples", &s.training_samples, sizeof(s.training_samples));
  h.updateField("training_amplitude", &s.training_amplitude, sizeof(s.training_amplitude));
  h.updateField("seed", &s.seed, sizeof(s.seed));
  h.updateField("basis.kkt_tolerance", &s.basis.kkt_tolerance, sizeof(s.basis.kkt_tolerance));
  h.updateField("basis.max_iterations", &s.basis.max_iterations, sizeof(s.basis.max_iterations));
  h.updateField("basis.initial_radius_factor", &s.basis.initial_radius_factor,
                sizeof(s.basis.initial_radius_factor));
  const char pou = s.surface_partition_of_unity ? 1 : 0;
  h.updateField("surface_partition_of_unity", &pou, 1);
  h.updateField("basis_drop_below", &s.basis_drop_below, sizeof(s.basis_drop_below));
  const char flags[2] = {char(elastic ? 1 : 0), char(inertial ? 1 : 0)};
  h.updateField("cubature flags", flags, sizeof(flags));
  if (s.basis_kind != ReducedBasisKind::Handles) {  // (the handle kind's keys stay as they were)
    const std::string kind = reducedBasisKindName(s.basis_kind);
    h.updateField("basis kind", kind.data(), kind.size());
    const ModalBasisSettings& m = s.modes;
    const char static_modes = m.static_modes ? 1 : 0;
    h.updateField("modes.static_modes", &static_modes, 1);
    h.updateField("modes.vibration_modes", &m.vibration_modes, sizeof(m.vibration_modes));
    h.updateField("modes.columns", &m.columns, sizeof(m.columns));
    h.updateField("modes.eigen_tolerance", &m.eigen_tolerance, sizeof(m.eigen_tolerance));
    h.updateField("modes.dependence_tolerance", &m.dependence_tolerance,
                  sizeof(m.dependence_tolerance));
    h.updateField("modes.seed", &m.seed, sizeof(m.seed));
    h.updateField("modes.rotation_weight", &m.rotation_weight, sizeof(m.rotation_weight));
  }
  return h.hexDigest();
}

// Random numbers from the 64-bit Mersenne twister with explicit transforms (the standard
// library's distributions differ between implementations; the cached data should not).
class SampleRandom {
 public:
  explicit SampleRandom(std::uint64_t seed) : engine_(seed) {}
  double uniform() { return double(engine_() >> 11) * 0x1.0p-53; }  // [0, 1)
  double normal() {                                                 // Box–Muller
    const double u1 = 1.0 - uniform(), u2 = uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
  }
  Vec3 normal3() {
    const double x = normal(), y = normal(), z = normal();
    return Vec3(x, y, z);
  }
  Vec3 unitDirection() {
    for (;;) {
      const Vec3 v = normal3();
      const double n = v.norm();
      if (n > 1e-12) return v / n;
    }
  }

 private:
  std::mt19937_64 engine_;
};

// Runs body(i) for i in [0, n) on OpenMP threads; the first exception is rethrown afterwards
// (an exception must not leave an OpenMP region).
template <class Body>
void parallelFor(int n, Body&& body) {
  std::string failure;
  bool failed = false, input_error = false;
#pragma omp parallel for schedule(dynamic, 4)
  for (int i = 0; i < n; ++i) {
    try {
      body(i);
    } catch (const std::exception& e) {
#pragma omp critical(flsh_reduced_data_failure)
      if (!failed) {
        failed = true;
        input_error = dynamic_cast<const InputError*>(&e) != nullptr;
        failure = e.what();
      }
    }
  }
  if (failed) {
    if (input_error) throw InputError(failure);
    throw Error(failure);
  }
}

// samples × columns, row s filled by row(s, block, k): the row is block's row k. Tasks take
// kSampleChunk samples each and fill a block of their own (column-major, so that one column's
// chunk of entries shares a cache line) copied into the result, instead of writing one entry per
// column `samples` doubles apart (at 2000 samples, each write on another page).
constexpr int kSampleChunk = 8;
// Rows `tail` (may be empty) are appended below the samples.
template <class RowFn>
MatX sampleRows(int samples, Eigen::Index columns, RowFn&& row, const MatX& tail = MatX()) {
  MatX A(samples + tail.rows(), columns);
  if (tail.size() > 0) A.bottomRows(tail.rows()) = tail;
  const int chunks = (samples + kSampleChunk - 1) / kSampleChunk;
  parallelFor(chunks, [&](int chunk) {
    const int first = chunk * kSampleChunk, n = std::min(kSampleChunk, samples - first);
    MatX block(n, columns);
    for (int k = 0; k < n; ++k) row(first + k, block, k);
    A.middleRows(first, n) = block;
  });
  return A;
}

Mat34 tetNodes(const MatX3& nodes, const MatX4i& tets, int t) {
  Mat34 X;
  for (int a = 0; a < 4; ++a) X.col(a) = nodes.row(tets(t, a)).transpose();
  return X;
}

// Handles: geodesic farthest-point sampling over the soft surface vertices, starting at the
// lowest-index soft surface vertex (deterministic, and independent of β).
VecXi chooseHandles(const VolumetricData& data, const BodyModel& body, int count) {
  const int V = body.numVertices();
  if (data.templ->mesh.num_surface_nodes != V || data.numNodes() < V)
    throw InputError("buildReducedData: the volumetric data has " +
                     std::to_string(data.templ->mesh.num_surface_nodes) +
                     " surface nodes, expected the body model's " + std::to_string(V) +
                     " vertices");
  const VecXi bone_of_vertex = data.bone_of_node.head(V);
  int first = -1, eligible = 0;
  for (int i = 0; i < V; ++i)
    if (bone_of_vertex[i] < 0) {
      if (first < 0) first = i;
      ++eligible;
    }
  if (count > eligible)
    throw InputError("buildReducedData: ReducedSettings::num_handles = " + std::to_string(count) +
                     ", expected at most the " + std::to_string(eligible) +
                     " soft-tissue surface nodes of this body");
  return farthestPointSurfaceHandles(data.rest_nodes.topRows(V), body.faces, count, first,
                                     bone_of_vertex);
}

// #N × H compressed basis from the dense weights, without the negligible entries.
SpMat sparseBasis(const MatX& weights) {
  std::vector<Triplet> entries;
  for (Eigen::Index h = 0; h < weights.cols(); ++h)
    for (Eigen::Index j = 0; j < weights.rows(); ++j)
      if (std::abs(weights(j, h)) >= detail::kBasisDropThreshold)
        entries.emplace_back(int(j), int(h), weights(j, h));
  SpMat basis(weights.rows(), weights.cols());
  basis.setFromTriplets(entries.begin(), entries.end());
  basis.makeCompressed();
  return basis;
}

// ReducedSettings::surface_partition_of_unity: φ̃_h = f φ_h / Σ_k φ_k with f harmonic (P1
// Laplacian), 1 on the soft surface nodes and 0 on the bone nodes. Nodes no handle reaches
// (Σ φ below 1e-9) keep φ = 0.
MatX surfacePartitionOfUnity(const VolumetricData& data, const MatX& weights) {
  const int N = data.numNodes(), V = data.templ->mesh.num_surface_nodes;
  TetMesh shaped = data.templ->mesh;
  shaped.nodes = data.rest_nodes;
  const SpMat K = cotangentLaplacian(shaped);
  // Free nodes: interior soft nodes; fixed: the surface (1 where soft) and the bone nodes (0).
  std::vector<int> free_index(size_t(N), -1);
  int free_count = 0;
  VecX fixed = VecX::Zero(N);
  for (int j = 0; j < N; ++j) {
    if (data.bone_of_node[j] >= 0) continue;
    if (j < V)
      fixed[j] = 1.0;
    else
      free_index[size_t(j)] = free_count++;
  }
  VecX f = fixed;
  if (free_count > 0) {
    std::vector<Triplet> entries;
    VecX rhs = VecX::Zero(free_count);
    for (int c = 0; c < K.outerSize(); ++c)
      for (SpMat::InnerIterator it(K, c); it; ++it) {
        const int r = free_index[size_t(it.row())];
        if (r < 0) continue;
        const int cc = free_index[size_t(c)];
        if (cc >= 0)
          entries.emplace_back(r, cc, it.value());
        else
          rhs[r] -= it.value() * fixed[c];
      }
    SpMat Kff(free_count, free_count);
    Kff.setFromTriplets(entries.begin(), entries.end());
    Eigen::SimplicialLDLT<SpMat> solver(Kff);
    if (solver.info() != Eigen::Success)
      throw Error(
          "buildReducedData: the harmonic fade of the surface partition of unity could "
          "not be factored");
    const VecX interior = solver.solve(rhs);
    for (int j = 0; j < N; ++j)
      if (free_index[size_t(j)] >= 0) f[j] = std::clamp(interior[free_index[size_t(j)]], 0.0, 1.0);
  }
  MatX out = MatX::Zero(weights.rows(), weights.cols());
  for (int j = 0; j < N; ++j) {
    if (data.bone_of_node[j] >= 0) continue;
    const double sum = weights.row(j).sum();
    if (sum > 1e-9) out.row(j) = (f[j] / sum) * weights.row(j);
  }
  return out;
}

// samples × #elastic elements (then the rows `tail` appended): the elastic energy (J) of each tet
// under random displacements of the subspace, of amplitudes log-uniform in [1 mm,
// training_amplitude]. Handle samples: every handle moves in a random direction by a random
// fraction of the amplitude, at most its reach (handle_reach, H, m). Modal samples: a random
// direction z ~ N(0, I) of the (mass-orthonormal) modes, scaled so that the largest node
// displacement is the amplitude and no surface vertex moves further than its reach (vertex_reach,
// #V, m). ModesAndHandles alternates the two.
MatX elasticSamples(const VolumetricData& data, const ReducedData& d, const ElasticTets& elements,
                    const VecX& handle_reach, const VecX& vertex_reach, int samples,
                    double amplitude, std::uint64_t seed, const MatX& tail) {
  const int H = d.numHandles(), r = d.numModes(), E = int(elements.tets.size());
  const double smallest = std::min(kSmallestTrainingAmplitude, amplitude);
  SampleRandom random(seed);
  std::vector<MatX> handle_displacements{size_t(samples)};  // each H × 3, m (or empty)
  // The modal samples' directions, then (one product for all: Ψ read once, not per sample) their
  // node displacements U (3#N × modal samples, column k: entry 3j + c), scaled in place.
  std::vector<int> modal_column(size_t(samples), -1);
  std::vector<double> modal_amplitude;
  MatX Z(r, samples);
  for (int s = 0; s < samples; ++s) {
    const double a = smallest * std::exp(random.uniform() * std::log(amplitude / smallest));
    const bool modal = r > 0 && (H == 0 || s % 2 == 0);
    if (!modal) {
      MatX& z = handle_displacements[size_t(s)];
      z.resize(H, 3);
      for (int h = 0; h < H; ++h)
        z.row(h) = (std::min(a, handle_reach[h]) * random.uniform()) * random.unitDirection();
      continue;
    }
    modal_column[size_t(s)] = int(modal_amplitude.size());
    for (int k = 0; k < r; ++k) Z(k, Eigen::Index(modal_amplitude.size())) = random.normal();
    modal_amplitude.push_back(a);
  }
  using NodeRows = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
  const Eigen::Index N = data.numNodes(), M = Eigen::Index(modal_amplitude.size());
  MatX U = M > 0 ? MatX(d.modes * Z.leftCols(M)) : MatX();
  for (Eigen::Index k = 0; k < M; ++k) {
    const VecX norms = Eigen::Map<const NodeRows>(U.col(k).data(), N, 3).rowwise().norm();
    double scale = norms.maxCoeff() > 0 ? modal_amplitude[size_t(k)] / norms.maxCoeff() : 0.0;
    for (Eigen::Index i = 0; i < vertex_reach.size(); ++i)
      if (norms[i] * scale > vertex_reach[i]) scale = vertex_reach[i] / norms[i];
    U.col(k) *= scale;
  }
  const MatX4i& tets = data.templ->mesh.tets;
  std::vector<PackedTet> packed{size_t(E)};  // what each sample reads of a tet, packed once
  for (int c = 0; c < E; ++c)
    packed[size_t(c)] = packTet(elements.rest[size_t(c)], elements.materials[size_t(c)], 1.0);
  return sampleRows(
      samples, E,
      [&](int s, MatX& block, int row) {
        const int k = modal_column[size_t(s)];
        const MatX u = k >= 0 ? MatX(Eigen::Map<const NodeRows>(U.col(k).data(), N, 3))
                              : MatX(d.basis * handle_displacements[size_t(s)]);  // #N × 3
        for (int c = 0; c < E; ++c) {
          const int t = elements.tets[size_t(c)];
          Mat34 ue;
          for (int a = 0; a < 4; ++a) ue.col(a) = u.row(tets(t, a)).transpose();
          block(row, c) = tetElasticEnergy(packed[size_t(c)], ue);
        }
      },
      tail);
}

// Node velocities (#N × 3) of skinned bone motions, joint velocities v and angular velocities ω of
// the bones (B × 3 each), plus `extra` node velocities (#N × 3, e.g. Φż; empty: none):
// v_j = Σ_b w_jb (v_b + ω_b × (X̄_j − J_b)) + extra_j = (W (v − ω × J))_j + extra_j + (W ω)_j × X̄_j.
MatX skinnedBoneVelocities(const MatX& W, const MatX3& X, const MatX3& J, const MatX& linear,
                           const MatX& angular, const MatX& extra = MatX()) {
  MatX omega_cross_joint(angular.rows(), 3);
  for (Eigen::Index b = 0; b < angular.rows(); ++b)
    omega_cross_joint.row(b) = Vec3(angular.row(b)).cross(Vec3(J.row(b))).transpose();
  MatX v = W * (linear - omega_cross_joint);
  if (extra.size() > 0) v += extra;
  const MatX skinned_angular = W * angular;
  for (Eigen::Index j = 0; j < v.rows(); ++j)
    v.row(j) += Vec3(skinned_angular.row(j)).cross(Vec3(X.row(j))).transpose();
  return v;
}

// Row r of A (samples × #T): Σ_{a∈t} (m_t/4)‖v_a‖² per tet t, from the nodes' ‖v‖².
void tetKineticEnergies(const VecX& speed_squared, const MatX4i& tets, const VecX& tet_masses,
                        MatX& A, Eigen::Index r) {
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    double sum = 0;
    for (int a = 0; a < 4; ++a) sum += speed_squared[tets(t, a)];
    A(r, t) = tet_masses[t] / 4 * sum;
  }
}

// samples × #T (then the rows `tail` appended): Σ_{a∈e} (m_e/4)‖v_a‖² (twice the lumped kinetic
// energy, J) of each tet for random skinned bone twists plus random subspace velocities: each
// handle's of RMS speed kHandleSpeed, the modes' ż ~ N(0, σ² I) with σ such that the soft nodes'
// mass-weighted RMS speed is kHandleSpeed (the modes are mass-orthonormal: Σ_j m_j ‖v_j‖² = ‖ż‖²).
MatX inertialSamples(const VolumetricData& data, const ReducedData& rom, const VecX& tet_masses,
                     int samples, std::uint64_t seed, const MatX& tail) {
  const MatX& W = data.templ->fields.weights;  // #N × bones
  const SpMat& basis = rom.basis;
  const int B = int(W.cols()), H = rom.numHandles(), r = rom.numModes();
  double soft_mass = 0.0;
  for (Eigen::Index t = 0; t < tet_masses.size(); ++t)
    for (int a = 0; a < 4; ++a)
      if (data.bone_of_node[data.templ->mesh.tets(t, a)] < 0) soft_mass += tet_masses[t] / 4;
  const double s_mode = r > 0 ? kHandleSpeed * std::sqrt(soft_mass / r) : 0.0;
  const MatX4i& tets = data.templ->mesh.tets;
  const int T = int(tets.rows());
  SampleRandom random(seed);
  struct Velocities {
    MatX bone_linear, bone_angular, handles;  // B × 3, B × 3, H × 3
    VecX modes;                               // r
  };
  std::vector<Velocities> draws{size_t(samples)};
  const double sv = kBoneSpeed / std::sqrt(3.0), sw = kBoneAngularSpeed / std::sqrt(3.0),
               sz = kHandleSpeed / std::sqrt(3.0);
  for (int s = 0; s < samples; ++s) {
    Velocities& d = draws[size_t(s)];
    d.bone_linear.resize(B, 3);
    d.bone_angular.resize(B, 3);
    d.handles.resize(H, 3);
    for (int b = 0; b < B; ++b) d.bone_linear.row(b) = sv * random.normal3();
    for (int b = 0; b < B; ++b) d.bone_angular.row(b) = sw * random.normal3();
    for (int h = 0; h < H; ++h) d.handles.row(h) = sz * random.normal3();
    d.modes.resize(r);
    for (int k = 0; k < r; ++k) d.modes[k] = s_mode * random.normal();
  }
  // Every sample's modal node velocities in one product (Ψ read once, not per sample).
  MatX Zdot(r, r > 0 ? samples : 0);
  for (int s = 0; s < samples && r > 0; ++s) Zdot.col(s) = draws[size_t(s)].modes;
  const MatX mode_velocities = r > 0 ? MatX(rom.modes * Zdot) : MatX();
  using NodeRows = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
  return sampleRows(
      samples, T,
      [&](int s, MatX& block, int row) {
        const Velocities& d = draws[size_t(s)];
        MatX extra = H > 0 ? MatX(basis * d.handles) : MatX::Zero(data.numNodes(), 3);
        if (r > 0)
          extra += Eigen::Map<const NodeRows>(mode_velocities.col(s).data(), extra.rows(), 3);
        const MatX v = skinnedBoneVelocities(W, data.rest_nodes, data.rest_joints, d.bone_linear,
                                             d.bone_angular, extra);
        tetKineticEnergies(v.rowwise().squaredNorm(), tets, tet_masses, block, row);
      },
      tail);
}

// Twice the lumped kinetic energy of each tet (rows × #T) for the skeleton's unit articulated
// motions — the root joint's translation and each bone's rotation about its joint, which carries
// the joints below it along (they translate, the bones below keep their orientation) — and for
// the sums of the pairs of them whose motions share kinetic energy (|Q_ik| > kRigidCoupling ·
// sqrt(Q_ii Q_kk), Q the articulated mass matrix). A cubature exact on these rows reproduces the
// skeleton's rigid inertia: the random velocities of inertialSamples leave it off by up to 2×
// in the light distal bones' directions (toes, wrists, hands), whose energy is a small part of
// any random sample.
constexpr double kRigidCoupling = 0.05;
MatX rigidMotionRows(const VolumetricData& data, const std::vector<int>& parents,
                     const VecX& tet_masses) {
  const MatX& W = data.templ->fields.weights;  // #N × bones
  const int B = int(W.cols()), N = data.numNodes(), D = 3 + 3 * B;
  const MatX4i& tets = data.templ->mesh.tets;
  const int T = int(tets.rows());
  const MatX3& J = data.rest_joints;
  // Per articulated DoF k: each bone's joint velocity and angular velocity (B × 6).
  std::vector<MatX> bone_motion(size_t(D), MatX::Zero(B, 6));
  for (int k = 0; k < D; ++k) {
    MatX& m = bone_motion[size_t(k)];
    for (int b = 0; b < B; ++b) {
      if (k >= 3 && (k - 3) / 3 == b) m(b, 3 + (k - 3) % 3) = 1.0;
      if (b == 0) {
        if (k < 3) m(0, k) = 1.0;
        continue;
      }
      const int p = parents[size_t(b)];
      const Vec3 omega = m.row(p).tail<3>().transpose();
      m.row(b).head<3>() = m.row(p).head<3>() + omega.cross(Vec3(J.row(b) - J.row(p))).transpose();
    }
  }
  // Node velocities per DoF (N × 3 each).
  std::vector<MatX> velocity(static_cast<size_t>(D));
  parallelFor(D, [&](int k) {
    const MatX& m = bone_motion[size_t(k)];
    velocity[size_t(k)] =
        skinnedBoneVelocities(W, data.rest_nodes, J, m.leftCols(3), m.rightCols(3));
  });
  VecX node_mass = VecX::Zero(N);
  for (int t = 0; t < T; ++t)
    for (int a = 0; a < 4; ++a) node_mass[tets(t, a)] += tet_masses[t] / 4;
  MatX Q(D, D);
  for (int i = 0; i < D; ++i)
    for (int k = i; k < D; ++k)
      Q(i, k) = Q(k, i) =
          (velocity[size_t(i)].cwiseProduct(velocity[size_t(k)]).rowwise().sum().array() *
           node_mass.array())
              .sum();
  std::vector<std::pair<int, int>> motions;
  for (int i = 0; i < D; ++i) {
    if (Q(i, i) > 0.0) motions.emplace_back(i, -1);
    for (int k = i + 1; k < D; ++k)
      if (std::abs(Q(i, k)) > kRigidCoupling * std::sqrt(Q(i, i) * Q(k, k)))
        motions.emplace_back(i, Q(i, k) > 0 ? k : -2 - k);  // the pair, or i minus k
  }
  MatX A(Eigen::Index(motions.size()), T);
  parallelFor(int(motions.size()), [&](int r) {
    const auto [i, code] = motions[size_t(r)];
    MatX v = velocity[size_t(i)];
    if (code >= 0) v += velocity[size_t(code)];
    if (code <= -2) v -= velocity[size_t(-2 - code)];
    tetKineticEnergies(v.rowwise().squaredNorm(), tets, tet_masses, A, r);
  });
  return A;
}

// The largest relative error |Σ_k w_k A(r, e_k) / Σ_t A(r, t) − 1| of a cubature over the rows
// of A (columns = template tets), rows with a zero total skipped.
double largestRowError(const MatX& A, const Cubature& c) {
  double largest = 0.0;
  for (Eigen::Index r = 0; r < A.rows(); ++r) {
    const double exact = A.row(r).sum();
    if (!(exact > 0.0)) continue;
    double approximate = 0.0;
    for (Eigen::Index k = 0; k < c.elements.size(); ++k)
      approximate += c.weights[k] * A(r, c.elements[k]);
    largest = std::max(largest, std::abs(approximate / exact - 1.0));
  }
  return largest;
}

// Each sample (row) divided by its total, so that every sample counts as much in the fit and in
// the error: the energies of the elastic samples span orders of magnitude (amplitudes from 1 mm
// to training_amplitude), and unscaled the largest few would decide the whole selection. A
// cubature exact on the scaled rows is exact on the unscaled ones.
MatX perSampleRelative(MatX A) {
  // The rows' totals summed column by column (the order of a row's own sum, A read in storage
  // order), then each column divided.
  VecX total = VecX::Zero(A.rows());
  for (Eigen::Index c = 0; c < A.cols(); ++c) total += A.col(c);
  for (Eigen::Index s = 0; s < A.rows(); ++s)
    if (!(total[s] > 0)) total[s] = 1;  // left as it is
  for (Eigen::Index c = 0; c < A.cols(); ++c) A.col(c).array() /= total.array();
  return A;
}

// Selection on `samples` training samples (seed), held-out error on a quarter as many (at least
// kHeldOutSamples, at most twice that) from seed + 1: a diagnostic, whose evaluation (every tet
// of every sample) once cost as much as the training's; columns mapped to template tet indices by
// `column_tets` (ascending, so the order is kept). `extra_rows` (may be empty): fixed rows added to
// the training samples only. sample_matrix(seed, count, tail): count samples × columns, then the
// rows `tail`.
template <class SampleFn>
Cubature trainCubature(SampleFn&& sample_matrix, int samples, int count, double tolerance,
                       std::uint64_t seed, const std::vector<int>& column_tets, double* test_error,
                       double* seconds_training, double* seconds_cubature,
                       const MatX& extra_rows = MatX()) {
  auto t0 = Clock::now();
  Cubature cubature;
  {
    const MatX training = perSampleRelative(sample_matrix(seed, samples, extra_rows));
    *seconds_training += secondsSince(t0);
    t0 = Clock::now();
    CubatureOptions options;
    options.count = count;
    options.tolerance = tolerance;
    cubature = selectCubature(training, options);
    *seconds_cubature += secondsSince(t0);
  }
  t0 = Clock::now();
  {
    const int held_out_samples =
        std::min(samples, std::clamp(samples / 4, kHeldOutSamples, 2 * kHeldOutSamples));
    const MatX held_out = perSampleRelative(sample_matrix(seed + 1, held_out_samples, MatX()));
    *seconds_training += secondsSince(t0);
    t0 = Clock::now();
    *test_error = cubatureRelativeError(held_out, cubature.elements, cubature.weights);
    *seconds_cubature += secondsSince(t0);
  }
  for (int k = 0; k < cubature.elements.size(); ++k)
    cubature.elements[k] = column_tets[size_t(cubature.elements[k])];
  return cubature;
}

// The cubatures the flags ask for on d's basis, then the cache entry.
void finishReducedData(const VolumetricData& data, const BodyModel& body,
                       const ReducedSettings& settings, bool elastic_cubature,
                       bool inertial_cubature, const AvatarCache* cache, ReducedData& d,
                       ReducedBuildReport& r) {
  auto t0 = Clock::now();
  const int samples = settings.training_samples;
  if (elastic_cubature) {
    t0 = Clock::now();
    const ElasticTets elements = deformableTets(data);
    VecX handle_reach(d.numHandles());
    for (int h = 0; h < d.numHandles(); ++h)
      handle_reach[h] = std::max(kMaxTrainingShear * data.tissue_thickness[d.handles[h]],
                                 kSmallestTrainingAmplitude);
    VecX vertex_reach(d.numModes() > 0 ? data.tissue_thickness.size() : 0);
    for (Eigen::Index i = 0; i < vertex_reach.size(); ++i)
      vertex_reach[i] =
          std::max(kMaxTrainingShear * data.tissue_thickness[i], kSmallestTrainingAmplitude);
    r.seconds_training += secondsSince(t0);
    d.elastic = trainCubature(
        [&](std::uint64_t seed, int count, const MatX& tail) {
          return elasticSamples(data, d, elements, handle_reach, vertex_reach, count,
                                settings.training_amplitude, seed, tail);
        },
        samples, settings.elastic_cubature_points, kElasticTrainingTolerance, settings.seed,
        elements.tets, &d.elastic_test_error, &r.seconds_training, &r.seconds_cubature);
    t0 = Clock::now();
    d.elastic_rest_stiffness = detail::subspaceRestStiffness(data, d, elements);
    r.seconds_cubature += secondsSince(t0);
  }
  if (inertial_cubature) {
    t0 = Clock::now();
    TetMesh shaped = data.templ->mesh;
    shaped.nodes = data.rest_nodes;
    const VecX tet_masses = tetVolumes(shaped).cwiseProduct(data.materials.density);
    std::vector<int> all_tets(size_t(data.numTets()));
    for (int t = 0; t < data.numTets(); ++t) all_tets[size_t(t)] = t;
    const MatX rigid_rows = rigidMotionRows(data, body.parents, tet_masses);
    r.seconds_training += secondsSince(t0);
    d.inertial = trainCubature(
        [&](std::uint64_t seed, int count, const MatX& tail) {
          return inertialSamples(data, d, tet_masses, count, seed, tail);
        },
        samples, settings.inertial_cubature_points, kInertialTrainingTolerance, settings.seed,
        all_tets, &d.inertial_test_error, &r.seconds_training, &r.seconds_cubature, rigid_rows);
    d.inertial_rigid_error = largestRowError(rigid_rows, d.inertial);
  }

  if (cache) {
    t0 = Clock::now();
    cache->store(d.key, detail::reducedDataArrays(d));
    r.seconds_cache_store += secondsSince(t0);
  }
}

}  // namespace

ModalBasisSettings defaultReducedModes() {
  ModalBasisSettings s;
  s.vibration_modes = 24;
  s.columns = 72;
  return s;
}

const char* reducedBasisKindName(ReducedBasisKind kind) {
  switch (kind) {
    case ReducedBasisKind::Handles:
      return "handles";
    case ReducedBasisKind::Modes:
      return "modes";
    case ReducedBasisKind::ModesAndHandles:
      return "modes+handles";
  }
  return "?";
}

ReducedBasisKind parseReducedBasisKind(const std::string& name, const std::string& where) {
  for (ReducedBasisKind kind :
       {ReducedBasisKind::Handles, ReducedBasisKind::Modes, ReducedBasisKind::ModesAndHandles})
    if (name == reducedBasisKindName(kind)) return kind;
  throw InputError(where + ": basis kind '" + name +
                   "', expected one of 'handles', 'modes', 'modes+handles'");
}

ReducedData buildReducedData(const VolumetricData& data, const BodyModel& body,
                             const ReducedSettings& settings, bool elastic_cubature,
                             bool inertial_cubature, const AvatarCache* cache,
                             ReducedBuildReport* report) {
  ReducedBuildReport local;
  ReducedBuildReport& r = report ? *report : local;
  const auto start = Clock::now();
  checkSettings(settings);
  if (!data.templ || data.bone_of_node.size() != data.numNodes() ||
      data.materials.density.size() != data.numTets())
    throw InputError(
        "buildReducedData: the volumetric data is incomplete (no template, or "
        "bone_of_node / materials of the wrong size), expected buildVolumetricData's "
        "output");
  const std::string key = reducedKey(data, settings, elastic_cubature, inertial_cubature);
  // Settings of the handle basis next to the modal basis alone (C++ code written when handles
  // were the default): said once, not an error (the scene file, the CLI and Python reject them).
  if (settings.basis_kind == ReducedBasisKind::Modes) {
    if (settings.num_handles != ReducedSettings().num_handles)
      r.warnings += "buildReducedData: ReducedSettings::num_handles = " +
                    std::to_string(settings.num_handles) +
                    " is not used by basis_kind = Modes (the default since 2026-12-02); set "
                    "basis_kind = Handles or ModesAndHandles for handles\n";
    if (settings.surface_partition_of_unity)
      r.warnings +=
          "buildReducedData: ReducedSettings::surface_partition_of_unity is not used by "
          "basis_kind = Modes (it rescales the handles' weights)\n";
  }

  if (cache) {
    const auto t0 = Clock::now();
    std::string problem;
    if (auto f = cache->load(key, &problem)) {
      try {
        ReducedData d =
            detail::readReducedData(*f, data, body, settings, elastic_cubature, inertial_cubature);
        d.key = key;
        r.from_cache = true;
        r.seconds_cache_load += secondsSince(t0);
        r.seconds_total = secondsSince(start);
        return d;
      } catch (const Error& e) {
        problem = std::string("avatar cache file ") + cache->pathFor(key) +
                  " does not hold reduced data (" + e.what() + "); rebuilding it";
      }
    }
    if (!problem.empty()) r.warnings += problem + "\n";
    r.seconds_cache_load += secondsSince(t0);
  }

  ReducedData d;
  d.key = key;
  d.basis_kind = settings.basis_kind;
  auto t0 = Clock::now();
  if (settings.basis_kind != ReducedBasisKind::Handles) {
    ModalBasis modal = computeModalBasis(data, settings.modes);
    const Eigen::Index keep = modal.basis.cols() - modal.basis.cols() % 3;
    d.modes = modal.basis.leftCols(keep);
    r.modes = modal.report;
    r.seconds_basis += secondsSince(t0);
  }
  if (settings.basis_kind == ReducedBasisKind::Modes) {
    d.basis.resize(data.numNodes(), 0);
    finishReducedData(data, body, settings, elastic_cubature, inertial_cubature, cache, d, r);
    r.seconds_total = secondsSince(start);
    return d;
  }
  t0 = Clock::now();
  d.handles = chooseHandles(data, body, settings.num_handles);
  r.seconds_handles = secondsSince(t0);

  t0 = Clock::now();
  const BoundedBiharmonicWeights bbw = computeBoundedBiharmonicWeights(
      data.templ->mesh, data.rest_nodes, d.handles, data.bone_of_node, settings.basis);
  // The far tails are dropped before the optional rescaling of the rows (whose soft surface rows
  // then still sum to 1).
  const MatX weights =
      (bbw.weights.array().abs() >= settings.basis_drop_below).select(bbw.weights, 0.0);
  d.basis = sparseBasis(settings.surface_partition_of_unity ? surfacePartitionOfUnity(data, weights)
                                                            : weights);
  d.basis_max_bound_violation = bbw.report.max_bound_violation;
  d.basis_max_constraint_error = bbw.report.max_constraint_error;
  d.basis_converged = bbw.report.converged;
  if (!bbw.report.converged)
    r.warnings +=
        "buildReducedData: the bounded biharmonic weights did not converge for every "
        "handle (largest KKT residual " +
        str(bbw.report.max_kkt_residual) +
        " of the tolerance, max_iterations = " + std::to_string(settings.basis.max_iterations) +
        "); using them as they are\n";
  r.seconds_basis += secondsSince(t0);
  finishReducedData(data, body, settings, elastic_cubature, inertial_cubature, cache, d, r);
  r.seconds_total = secondsSince(start);
  return d;
}

VecX inertialNodeMasses(const VolumetricData& data, const Cubature& inertial) {
  const std::string fn = "inertialNodeMasses: ";
  if (!data.templ) throw InputError(fn + "the volumetric data has no template mesh");
  const int T = data.numTets();
  if (inertial.elements.size() != inertial.weights.size())
    throw InputError(fn + "the cubature has " + std::to_string(inertial.elements.size()) +
                     " elements and " + std::to_string(inertial.weights.size()) +
                     " weights, expected as many");
  if (data.materials.density.size() != T)
    throw InputError(fn + "materials.density has " + std::to_string(data.materials.density.size()) +
                     " entries, expected #T = " + std::to_string(T));
  const MatX4i& tets = data.templ->mesh.tets;
  VecX masses = VecX::Zero(data.numNodes());
  for (int k = 0; k < inertial.elements.size(); ++k) {
    const int t = inertial.elements[k];
    if (t < 0 || t >= T)
      throw InputError(fn + "cubature element " + std::to_string(k) + " = " + std::to_string(t) +
                       ", expected a tet index in [0, " + std::to_string(T) + ")");
    const Mat34 X = tetNodes(data.rest_nodes, tets, t);
    const double volume = tetSignedVolume(X);
    const double quarter = inertial.weights[k] * data.materials.density[t] * volume / 4;
    for (int a = 0; a < 4; ++a) masses[tets(t, a)] += quarter;
  }
  return masses;
}

}  // namespace flsh
