// The reduced data's arrays in its cache entry (the avatar cache's third level, reduced_data.h):
// written as they are, read back with every value checked against the volumetric data and the
// settings it was built for (a damaged entry is an InputError naming the file and the key).
// Private to volume/.
#pragma once

#include <string>

#include "flsh/body/body_model.h"
#include "flsh/format/npz.h"
#include "flsh/volume/reduced_data.h"

namespace flsh::detail {

/// Basis entries below this are dropped (they only cost memory and time in the simulation); a
/// stored basis has none.
constexpr double kBasisDropThreshold = 1e-12;

/// Modal columns as ReducedData::modes holds them: 3·#nodes × r, finite, r a positive multiple of
/// 3, zero rows on bone nodes. InputError starting with `where` otherwise (the cache reader's
/// file and key, or SoftAvatar::setReducedData's field).
void checkModes(const VolumetricData& data, const MatX& modes, const std::string& where);

/// The arrays of `d` for its cache entry.
io::NpzWriter reducedDataArrays(const ReducedData& d);

/// The reduced data of a cache entry, checked: distinct soft-tissue surface handles, a
/// column-major basis of weights in [0, 1] on soft-tissue nodes, cubatures of ascending tets in
/// range with positive weights (empty when off), finite figures.
ReducedData readReducedData(const io::NpzFile& f, const VolumetricData& data, const BodyModel& body,
                            const ReducedSettings& settings, bool elastic, bool inertial);

}  // namespace flsh::detail
