#pragma once
/// \file
/// `concord sim --render`: stereo images of a simulated team (docs/simulator.md, "Rendered
/// images"). The world is a hall of textured quads around the robots' paths (walls, floor and
/// ceiling), textured pillars standing clear of the paths, and one textured cube per object
/// landmark, centred on its ground-truth position. Textures are real photographs (EuRoC frames,
/// data/README.md) with a random offset and flip per quad; sampling is trilinear on a mip-map so
/// distant surfaces do not alias. Each robot's rectified stereo pair is rendered by casting one
/// ray per pixel (a z-buffer over the quads' screen boxes), with Gaussian pixel noise, and
/// written in the KITTI odometry layout with exact ground truth:
///
///     OUT/robot_NN/image_0/%06d.png, image_1/%06d.png   left and right, 8-bit grey
///     OUT/robot_NN/calib.txt      P0, P1 of the rectified pinhole pair
///     OUT/robot_NN/times.txt      one time a frame (the frame rate)
///     OUT/robot_NN/poses.txt      T_world_cam0 per frame (KITTI's convention)
///     OUT/robot_NN/detections.csv boxes of the visible objects (frame,track_id,class,x_min,...)
///     OUT/world.csv               the quads' geometry (for evaluations)
///
/// next to the simulated dataset itself (the simulator's exact observations), so the whole chain
/// images -> front-end -> filter -> consensus can be compared with the exact one.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "concord/dataset/dataset.h"
#include "concord/estimator/types.h"

namespace concord::sim {

/// Parameters of the rendered world and images (the CLI flag is in brackets).
struct RenderOptions {
  /// Image size in pixels (--render-width, --render-height). The focal length follows from the
  /// simulation's horizontal field of view; its vertical field of view from the aspect ratio.
  int width = 752;
  int height = 480;
  /// Standard deviation of the pixel noise added to every image, grey levels (--render-noise).
  double image_noise = 1.0;
  /// Edge of each object cube, metres (--render-object-size).
  double object_size = 0.6;
  /// Pillars per 100 square metres of the hall floor (--render-pillars).
  double pillar_density = 1.5;
  /// Samples a pixel takes along each axis, averaged (--render-supersampling): a camera's pixel
  /// integrates the light over its area. One sample at the pixel centre reads the texture at a
  /// sub-pixel phase that changes from frame to frame, so its content changes with the phase
  /// (the bilinear interpolation's blur varies with it) and tracked corners wander by a tenth of
  /// a pixel a frame that a real camera would not add (docs/frontend.md, "Rendered images").
  int supersampling = 3;
  /// Frame rate written to times.txt, Hz.
  double frame_rate = 20.0;
  /// Folder of the photographs used as textures (every PNG under it); the repository's EuRoC
  /// frames, data/euroc-v101-static-4, by default (--render-textures).
  std::filesystem::path textures;

  [[nodiscard]] std::vector<std::string> validate() const;
};

/// The pinhole camera of the rendered images: fx = fy = (width / 2) / tan(hfov / 2), principal
/// point at the image centre, the simulation's extrinsics (T_cam_body, baseline).
StereoCamera render_camera(const StereoCamera& simulated, double horizontal_fov_degrees,
                           const RenderOptions& options);

/// A world of textured planar quads (rectangles).
class TexturedWorld {
 public:
  /// One rectangle: corner + s * edge_u + t * edge_v, s, t in [0, 1].
  struct Quad {
    Eigen::Vector3d corner = Eigen::Vector3d::Zero();
    Eigen::Vector3d edge_u = Eigen::Vector3d::UnitX();
    Eigen::Vector3d edge_v = Eigen::Vector3d::UnitY();
    int texture = 0;
    /// Texture pixels per metre, offset of the texture (texels) and brightness gain.
    double texels_per_metre = 100.0;
    Eigen::Vector2d texture_offset = Eigen::Vector2d::Zero();
    double gain = 1.0;
    /// The object landmark this quad belongs to, or -1 for scenery.
    LandmarkId object = -1;
  };

  /// Where a ray first meets the world.
  struct Hit {
    double distance =
        0.0;  ///< along the (unnormalized) direction: the point is origin + distance * direction
    int quad = -1;
  };

  /// Loads the textures (every *.png under `folder`, sorted by path). Throws std::runtime_error if
  /// there is none or one cannot be read.
  explicit TexturedWorld(const std::filesystem::path& texture_folder);
  /// A world without textures: geometry for cast() only (render() throws std::logic_error).
  TexturedWorld();
  ~TexturedWorld();
  TexturedWorld(TexturedWorld&&) noexcept;
  TexturedWorld& operator=(TexturedWorld&&) noexcept;

  int texture_count() const;
  void add_quad(const Quad& quad);
  /// A box of the given half extents turned by `yaw` about world z: its six faces, each in the
  /// style of `style` with its own texture offset and gain drawn from `seed`.
  void add_box(const Eigen::Vector3d& centre, const Eigen::Vector3d& half_extent, double yaw,
               const Quad& style, std::uint64_t seed);
  const std::vector<Quad>& quads() const { return quads_; }

  /// An object landmark: a cube (style.object = id) remembered with its centre and size.
  struct Cube {
    LandmarkId id = 0;
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double half_size = 0.0;
    double yaw = 0.0;
    /// The eight corners in world coordinates.
    std::vector<Eigen::Vector3d> corners() const;
  };
  void add_object_cube(const Cube& cube, const Quad& style, std::uint64_t seed);
  const std::vector<Cube>& cubes() const { return cubes_; }

  /// The first quad hit by the ray origin + d * direction, d > 1e-9.
  [[nodiscard]] std::optional<Hit> cast(const Eigen::Vector3d& origin,
                                        const Eigen::Vector3d& direction) const;

  /// The 8-bit grey image of a pinhole camera (K, pose T_world_camera, optical z forward) of
  /// width x height pixels, row-major; noise of `noise_sigma` grey levels from `noise_seed`. Each
  /// pixel is the mean of `supersampling` x `supersampling` samples spread evenly over its area
  /// (on the surface its centre sees).
  std::vector<std::uint8_t> render(const Eigen::Matrix3d& K,
                                   const Eigen::Isometry3d& T_world_camera, int width, int height,
                                   double noise_sigma, std::uint64_t noise_seed,
                                   int supersampling = 1) const;

 private:
  class Textures;
  std::unique_ptr<Textures> textures_;
  std::vector<Quad> quads_;
  std::vector<Cube> cubes_;
};

/// The world of a simulated dataset: a hall around every path, pillars clear of the paths and
/// objects, a cube per object. Objects closer than a cube's reach to some robot's path would be
/// flown through; their ids are returned in `removed_objects` and must be taken out of the
/// dataset (remove_objects).
TexturedWorld build_world(const dataset::Dataset& simulated, const RenderOptions& options,
                          std::uint64_t seed, std::vector<LandmarkId>& removed_objects);

/// The quads' geometry as CSV (`object,corner_x,corner_y,corner_z,u_x,u_y,u_z,v_x,v_y,v_z`, object
/// -1 for scenery), written as world.csv next to rendered sequences so evaluations can cast rays
/// into the world without rebuilding it.
std::string format_world_geometry(const TexturedWorld& world);

/// Reads world.csv into a world without textures. Throws std::runtime_error naming the file and
/// line on bad input.
[[nodiscard]] TexturedWorld read_world_geometry(const std::filesystem::path& file);

/// Takes objects out of a dataset: ground truth and every robot's observations.
void remove_objects(dataset::Dataset& data, const std::vector<LandmarkId>& ids);

/// The visible objects' boxes in the left image of a pose: the bounding box of the cube's
/// projected corners, for cubes in front of the camera whose centre is unoccluded (the ray from
/// the left camera to the centre first meets the cube), at a depth in [min_depth, max_depth],
/// with the whole box inside the image. Sorted by id.
struct ObjectBox {
  LandmarkId id = 0;
  double x_min = 0.0, y_min = 0.0, x_max = 0.0, y_max = 0.0;
};
std::vector<ObjectBox> visible_object_boxes(const TexturedWorld& world, const StereoCamera& camera,
                                            const Eigen::Isometry3d& T_world_body, int width,
                                            int height, double min_depth, double max_depth);

/// Renders every robot of `simulated` (whose camera is the simulation's) into `out`/robot_NN in
/// the KITTI layout described above. Robots are rendered in parallel threads. `progress` is
/// called (from any thread, serialized) after each frame with (frames done, frames in all).
void write_rendered_sequences(const dataset::Dataset& simulated, const TexturedWorld& world,
                              const StereoCamera& camera, const RenderOptions& options,
                              double min_depth, double max_depth, std::uint64_t seed,
                              const std::filesystem::path& out,
                              const std::function<void(long long, long long)>& progress = {});

}  // namespace concord::sim
