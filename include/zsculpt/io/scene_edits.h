#pragma once
// Scene-file edits (io::SceneEdit, the plain data io reads) as the editing module's
// commands. In io, which may depend on editing (never the other way: the editing module
// knows nothing of files or scenes). Header-only: it reads plain structs on both sides.

#include <vector>

#include "zsculpt/editing/schedule.h"
#include "zsculpt/io/scene.h"

namespace zsculpt::io {

inline editing::BrushMode fromScene(io::BrushMode mode) {
  switch (mode) {
    case io::BrushMode::Set:
      return editing::BrushMode::Set;
    case io::BrushMode::Add:
      return editing::BrushMode::Add;
    case io::BrushMode::Multiply:
      return editing::BrushMode::Multiply;
    case io::BrushMode::Smooth:
      return editing::BrushMode::Smooth;
  }
  return editing::BrushMode::Set;
}

inline editing::Falloff fromScene(io::BrushFalloff falloff) {
  switch (falloff) {
    case io::BrushFalloff::Smooth:
      return editing::Falloff::Smooth;
    case io::BrushFalloff::Sphere:
      return editing::Falloff::Sphere;
    case io::BrushFalloff::Linear:
      return editing::Falloff::Linear;
    case io::BrushFalloff::Sharp:
      return editing::Falloff::Sharp;
    case io::BrushFalloff::Constant:
      return editing::Falloff::Constant;
  }
  return editing::Falloff::Smooth;
}

inline editing::DistanceKind fromScene(io::BrushDistance distance) {
  return distance == io::BrushDistance::Euclidean ? editing::DistanceKind::Euclidean
                                                  : editing::DistanceKind::Surface;
}

inline editing::Brush fromScene(const io::BrushSettings& s) {
  editing::Brush b;
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
inline editing::TimedEdit fromScene(const io::SceneEdit& edit) {
  editing::TimedEdit timed;
  timed.time = edit.time;
  switch (edit.kind) {
    case io::EditKind::Brush: {
      editing::Dab dab{fromScene(edit.brush), editing::BrushCentre::atVertex(0)};
      if (edit.centerVertex)
        dab.centre = editing::BrushCentre::atVertex(*edit.centerVertex);
      else if (edit.centerPoint)
        dab.centre = editing::BrushCentre::atPoint(*edit.centerPoint);
      timed.command = dab;
      break;
    }
    case io::EditKind::Global:
      timed.command = editing::GlobalEdit{fromScene(edit.brush)};
      break;
    case io::EditKind::Relax:
      timed.command = editing::Relax{};
      break;
    case io::EditKind::ScaleRest:
      timed.command = editing::ScaleRest{edit.factor};
      break;
  }
  return timed;
}

/// The scene's edits as a schedule (sorted by time, file order kept for equal times).
inline editing::EditSchedule scheduleFromScene(const std::vector<io::SceneEdit>& edits) {
  std::vector<editing::TimedEdit> timed;
  timed.reserve(edits.size());
  for (size_t k = 0; k < edits.size(); ++k) {
    timed.push_back(fromScene(edits[k]));
    timed.back().source = k;
  }
  return editing::EditSchedule(std::move(timed));
}

}  // namespace zsculpt::io
