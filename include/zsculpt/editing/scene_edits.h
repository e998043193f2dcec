#pragma once
// Scene-file edits (io::SceneEdit, plain data read by the io module) as edit commands.
//
// Header-only on purpose: the zsculpt_editing library depends on zsculpt_physics alone,
// and this adapter only reads io's plain structs, so it costs a caller that already links
// zsculpt_io (the command line, the app) nothing and the editing library no dependency.

#include <vector>

#include "zsculpt/editing/schedule.h"
#include "zsculpt/io/scene.h"

namespace zsculpt::editing {

inline BrushMode fromScene(io::BrushMode mode) {
  switch (mode) {
    case io::BrushMode::Set:
      return BrushMode::Set;
    case io::BrushMode::Add:
      return BrushMode::Add;
    case io::BrushMode::Multiply:
      return BrushMode::Multiply;
    case io::BrushMode::Smooth:
      return BrushMode::Smooth;
  }
  return BrushMode::Set;
}

inline Falloff fromScene(io::BrushFalloff falloff) {
  switch (falloff) {
    case io::BrushFalloff::Smooth:
      return Falloff::Smooth;
    case io::BrushFalloff::Sphere:
      return Falloff::Sphere;
    case io::BrushFalloff::Linear:
      return Falloff::Linear;
    case io::BrushFalloff::Sharp:
      return Falloff::Sharp;
    case io::BrushFalloff::Constant:
      return Falloff::Constant;
  }
  return Falloff::Smooth;
}

inline DistanceKind fromScene(io::BrushDistance distance) {
  return distance == io::BrushDistance::Euclidean ? DistanceKind::Euclidean : DistanceKind::Surface;
}

inline Brush fromScene(const io::BrushSettings& s) {
  Brush b;
  b.property = s.property;
  b.mode = fromScene(s.mode);
  b.value = s.value;
  b.strength = s.strength;
  b.radius = s.radius;
  b.falloff = fromScene(s.falloff);
  b.distance = fromScene(s.distance);
  return b;
}

/// One scene edit as a timed command. A dab without a centre (the scene reader refuses
/// those) lands on vertex 0.
inline TimedEdit fromScene(const io::SceneEdit& edit) {
  TimedEdit timed;
  timed.time = edit.time;
  switch (edit.kind) {
    case io::EditKind::Brush: {
      Dab dab{fromScene(edit.brush), BrushCentre::atVertex(0)};
      if (edit.centerVertex)
        dab.centre = BrushCentre::atVertex(*edit.centerVertex);
      else if (edit.centerPoint)
        dab.centre = BrushCentre::atPoint(*edit.centerPoint);
      timed.command = dab;
      break;
    }
    case io::EditKind::Global:
      timed.command = GlobalEdit{fromScene(edit.brush)};
      break;
    case io::EditKind::Relax:
      timed.command = Relax{};
      break;
    case io::EditKind::ScaleRest:
      timed.command = ScaleRest{edit.factor};
      break;
  }
  return timed;
}

/// The scene's edits as a schedule (sorted by time, file order kept for equal times).
inline EditSchedule scheduleFromScene(const std::vector<io::SceneEdit>& edits) {
  std::vector<TimedEdit> timed;
  timed.reserve(edits.size());
  for (size_t k = 0; k < edits.size(); ++k) {
    timed.push_back(fromScene(edits[k]));
    timed.back().source = k;
  }
  return EditSchedule(std::move(timed));
}

}  // namespace zsculpt::editing
