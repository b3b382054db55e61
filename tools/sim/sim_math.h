#pragma once
// Small helpers shared by the simulator (simulator.cc) and the renderer (render.cc).

#include <Eigen/Geometry>
#include <cstdint>

namespace concord::sim {

/// SplitMix64 (Steele, Lea, Flood): a fixed, portable mixing of a 64-bit value. Seeds the
/// random streams of the simulation and the textures of the rendered world.
inline std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

/// The rotation by `yaw` radians about the world's z axis.
inline Eigen::Matrix3d yaw_rotation(double yaw) {
  return Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

}  // namespace concord::sim
