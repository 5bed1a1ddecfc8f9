// The outputs of a simulated scene (docs/scene_format.md, "Outputs"): a PLY mesh per saved
// frame and avatar, states.npz, animation.glb and sheet.png.
//
// SceneRecorder keeps per saved frame only what the enabled outputs need: PLY meshes are
// written as the frames come, sheet.png keeps only the frames it shows, and only states.npz
// and animation.glb keep data of every saved frame (bytesPerFrame). With those two off, a run
// of any length uses constant memory.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/io/scene_file.h"
#include "flsh/sim/simulable.h"

namespace flsh::io {

/// One avatar of the scene as the outputs name and draw it.
struct RecordedAvatar {
  std::string name;                            ///< names meshes/<name>/ and the npz keys
  std::shared_ptr<const Simulable> simulable;  ///< read at every record()
  bool soft = false;  ///< "fem" or "rom": soft-tissue displacements (npz key, sheet colours)
};

class SceneRecorder {
 public:
  /// `outputs` says what to write (its `dir` is ignored: everything goes below `dir`, e.g. a
  /// staging folder). `frames` is how many times record() will be called (frame 0 included):
  /// sheet.png's panels are chosen from it. Throws InputError if frames < 1.
  SceneRecorder(const OutputSpec& outputs, std::string dir, std::vector<RecordedAvatar> avatars,
                std::vector<Collider> colliders, double time_step, int frames);

  /// Bytes held in memory per saved frame by the enabled outputs, counted up to the moment
  /// they are written (the frames, then their stacked copies for states.npz, ~3× the frames).
  static double bytesPerFrame(const OutputSpec& outputs, const std::vector<RecordedAvatar>& avatars,
                              size_t num_colliders);

  /// Records the scene's current state as the next saved frame, at time t (s); writes its PLY
  /// meshes at once. Throws Error after `frames` calls.
  void record(double t);

  /// Writes states.npz, animation.glb and sheet.png as enabled (each atomically) and returns
  /// the names of everything written ("meshes/<avatar>/frame_*.ply", "states.npz", …).
  /// Throws Error unless every frame was recorded.
  std::vector<std::string> finish();

  /// Largest ‖u_i‖ over the surface vertices and the saved frames of avatar i, mm (0 for a
  /// skeleton avatar).
  double maxDisplacementMm(size_t avatar) const { return max_displacement_mm_[avatar]; }
  /// The colour scale of sheet.png's soft avatars, mm (valid after finish()): the
  /// kSheetScaleQuantile-quantile of ‖u_i‖ over the surface vertices of every soft avatar in
  /// every shown frame (the largest value if that quantile is 0); larger values share the top
  /// colour. The sheet draws it as a colour bar in mm below the frames.
  double sheetMaxDisplacementMm() const { return sheet_max_mm_; }
  /// The quantile that sets the sheet's colour scale: 0.99, so that a few flopping vertices
  /// (1 % of the shown values) do not leave the rest of the body in the bottom colour.
  static constexpr double kSheetScaleQuantile = 0.99;

 private:
  struct AvatarFrames;
  void writeNpz() const;
  void writeGltf() const;
  void writePng();

  OutputSpec outputs_;
  std::string dir_;
  std::vector<RecordedAvatar> avatars_;
  std::vector<Collider> colliders_;
  double time_step_;
  int frames_, recorded_ = 0;
  std::vector<int> shown_;           ///< the sheet's frames, increasing
  std::vector<double> shown_times_;  ///< their times, s (labels)
  std::vector<double> times_;
  std::vector<std::vector<Vec3>> collider_offsets_;  ///< per collider, per kept frame
  std::vector<std::shared_ptr<AvatarFrames>> data_;
  std::vector<double> max_displacement_mm_;
  double sheet_max_mm_ = 0.0;
};

}  // namespace flsh::io
