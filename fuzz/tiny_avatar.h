// A tiny avatar for the avatar-cache fuzz target and its seed corpus: a tetrahedron body (4
// vertices, 2 bones, 1 shape and 1 pose direction) whose volumetric template adds the centroid
// as the one interior node (4 tets), with materials of the default model at β = 0. Small
// enough for a seed corpus of a few kB, valid for readTemplateCacheArrays and
// readDataCacheArrays.
#pragma once

#include <memory>

#include "flsh/volume/volumetric_data.h"

namespace flsh::fuzz {

inline BodyModel tinyBody() {
  BodyModel body;
  body.v_template.resize(4, 3);
  body.v_template << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  body.faces.resize(4, 3);  // outward (counter-clockwise seen from outside)
  body.faces << 1, 2, 3, 0, 3, 2, 0, 1, 3, 0, 2, 1;
  body.weights.resize(4, 2);
  body.weights << 1, 0, 0.5, 0.5, 0, 1, 0.25, 0.75;
  body.shapedirs = MatX::Constant(12, 1, 0.01);
  body.posedirs = MatX::Constant(12, 1, 0.02);
  body.parents = {-1, 0};
  body.source = "tiny fuzz body";
  return body;
}

inline std::shared_ptr<VolumetricTemplate> tinyTemplate(const BodyModel& body) {
  auto templ = std::make_shared<VolumetricTemplate>();
  TetMesh& mesh = templ->mesh;
  mesh.nodes.resize(5, 3);
  mesh.nodes.topRows(4) = body.v_template;
  mesh.nodes.row(4) << 0.25, 0.25, 0.25;
  mesh.tets.resize(4, 4);  // each boundary face (a, b, c) with the centroid, as (a, c, b, 4)
  for (int f = 0; f < 4; ++f)
    mesh.tets.row(f) << body.faces(f, 0), body.faces(f, 2), body.faces(f, 1), 4;
  mesh.num_surface_nodes = 4;
  InteriorFields& fields = templ->fields;
  fields.weights.resize(5, 2);
  fields.weights.topRows(4) = body.weights;
  fields.weights.row(4) << 0.45, 0.55;
  fields.shapedirs = MatX::Constant(15, 1, 0.01);
  fields.posedirs = MatX::Constant(15, 1, 0.02);
  templ->quality = {30, 120, 1.5, 1.2, 0.04};
  templ->key = std::string(64, 'a');
  return templ;
}

/// The shape level at β = 0 on tinyTemplate(): node 4 on bone 1 (its largest weight), the
/// tets a mix of skin fractions, materials mixed from the default model.
inline VolumetricData tinyData(const BodyModel& body) {
  VolumetricData d;
  d.templ = tinyTemplate(body);
  d.material_model = MaterialModel::defaults(1);
  d.rest_nodes = d.templ->mesh.nodes;
  d.bone_of_node.resize(5);
  d.bone_of_node << -1, -1, -1, -1, 1;
  d.tissue_thickness = VecX::Constant(4, 0.02);
  TetMaterials& m = d.materials;
  m.skin_fraction.resize(4);
  m.skin_fraction << 0, 1, 0.3, 0.7;
  const VecX betas = VecX::Zero(1);
  auto value = [&](const char* q, int layer) { return d.material_model.value(q, layer, betas); };
  m.density.resize(4);
  m.fung.resize(4);
  m.young.resize(4, 3);
  m.poisson.resize(4, 3);
  m.shear.resize(4, 3);
  m.layer.resize(4);
  for (int t = 0; t < 4; ++t) {
    const double s = m.skin_fraction[t];
    auto mixed = [&](const char* q) {
      return s * value(q, MaterialModel::kSkin) + (1 - s) * value(q, MaterialModel::kSoftTissue);
    };
    m.density[t] = mixed("density");
    m.fung[t] = mixed("fung_gamma");
    m.shear.row(t) << mixed("G12"), mixed("G13"), mixed("G23");
    const int layer = s >= 0.5 ? MaterialModel::kSkin : MaterialModel::kSoftTissue;
    m.young.row(t) << value("E1", layer), value("E2", layer), value("E3", layer);
    m.poisson.row(t) << value("nu12", layer), value("nu13", layer), value("nu23", layer);
    m.layer[t] = layer;
    m.frame.push_back(Mat3::Identity());
  }
  d.key = std::string(64, 'b');
  return d;
}

}  // namespace flsh::fuzz
