// The volumetric body's two levels in the avatar cache (volumetric_data.h): the arrays each level
// stores, and their checks on load. A cache entry's checksum only proves that the file is the
// one written; these checks make sure that what it holds could have been built for this body,
// so that an entry edited and re-checksummed (or written by a buggy build) is rebuilt instead
// of simulated.
#pragma once

#include "flsh/format/npz.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh {

/// Template level: nodes (#N × 3), tets (#T × 4, int64), weights (#N × B), shapedirs (3#N × K),
/// posedirs (3#N × P), quality (5).
io::NpzWriter templateCacheArrays(const VolumetricTemplate& templ);

/// Reads the template level of `body` into templ.mesh, .fields and .quality. Throws
/// InputError naming the file and the key unless: nodes are finite with the body's vertices
/// as rows 0..V−1 exactly and more rows after them; the tets form a valid mesh of them
/// (validateTetMesh: indices in range and distinct, positive volumes, boundary = the body's
/// faces, every node used); weights, shapedirs and posedirs are finite with the body's own
/// rows on the surface, and weights are ≥ 0 with rows summing to 1; quality is finite.
void readTemplateCacheArrays(const io::NpzFile& f, const BodyModel& body,
                             VolumetricTemplate& templ);

/// Shape level: bone_of_node (#N), tissue_thickness (V), density, young, poisson, shear, fung,
/// skin_fraction, frame (#T × 9, row-major 3 × 3) and layer.
io::NpzWriter dataCacheArrays(const VolumetricData& data);

/// Reads the shape level into data.bone_of_node, .tissue_thickness and .materials; data.templ
/// and data.material_model must be set (betas: the padded β the entry was built for). Throws
/// InputError naming the file and the key unless: every bone node's bone is in [0, B) and
/// one of its largest weights (−1 for soft tissue); tissue thickness is finite and ≥ 0; skin
/// fractions are in [0, 1] and each layer is the one holding most of the tet; density, Fung
/// exponent and shear moduli are the model's skin / soft-tissue mixture at β (relative 1e-9);
/// Young's moduli are finite and > 0 and with the Poisson ratios give a positive-definite
/// compliance; frames are rotations (1e-9).
void readDataCacheArrays(const io::NpzFile& f, const VecX& betas, VolumetricData& data);

}  // namespace flsh
