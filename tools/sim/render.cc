#include "sim/render.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <numbers>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <thread>

#include "concord/dataset/result_io.h"
#include "concord/frontend/detections.h"
#include "concord/frontend/sequence.h"
#include "sim/sim_math.h"

namespace concord::sim {

namespace fs = std::filesystem;

namespace {

/// A small deterministic stream of uniforms (the world's layout; not <random>'s distributions,
/// whose output differs between standard libraries).
class Uniform {
 public:
  explicit Uniform(std::uint64_t seed) : state_(splitmix64(seed)) {}
  double operator()() {
    state_ = splitmix64(state_);
    return static_cast<double>(state_ >> 11) * 0x1.0p-53;
  }
  double operator()(double low, double high) { return low + (high - low) * (*this)(); }

 private:
  std::uint64_t state_;
};

/// Standard normal variates for pixel noise, looked up by a hash of (seed, pixel).
class NoiseTable {
 public:
  NoiseTable() {
    Uniform uniform(0x6e6f697365ULL);
    for (std::size_t index = 0; index < values_.size(); index += 2) {
      const double radius = std::sqrt(-2.0 * std::log(1.0 - uniform()));
      const double angle = 2.0 * std::numbers::pi * uniform();
      values_[index] = static_cast<float>(radius * std::cos(angle));
      values_[index + 1] = static_cast<float>(radius * std::sin(angle));
    }
  }
  float at(std::uint64_t seed, std::uint64_t pixel) const {
    return values_[splitmix64(seed ^ (pixel * 0x9e3779b97f4a7c15ULL)) & (values_.size() - 1)];
  }

 private:
  std::array<float, 1 << 16> values_{};
};

const NoiseTable& noise_table() {
  static const NoiseTable table;
  return table;
}

/// Index into [0, n) of an integer coordinate under mirrored repetition (period 2n).
inline int mirror(int i, int n) {
  const int period = 2 * n;
  int m = i % period;
  if (m < 0) m += period;
  return m < n ? m : period - 1 - m;
}

constexpr double kNearPlane = 0.05;

}  // namespace

// -------------------------------------------------------------------------------------------------
// Textures: mip-mapped float images, sampled trilinearly with mirrored repetition.

class TexturedWorld::Textures {
 public:
  explicit Textures(const fs::path& folder) {
    std::vector<fs::path> files;
    if (fs::is_directory(folder)) {
      for (const auto& entry : fs::recursive_directory_iterator(folder)) {
        if (entry.is_regular_file() && entry.path().extension() == ".png") {
          files.push_back(entry.path());
        }
      }
    }
    std::sort(files.begin(), files.end());
    if (files.empty()) {
      throw std::runtime_error(folder.string() + ": no PNG textures found");
    }
    for (const fs::path& file : files) {
      cv::Mat image = cv::imread(file.string(), cv::IMREAD_GRAYSCALE);
      if (image.empty()) throw std::runtime_error(file.string() + ": cannot read the texture");
      std::vector<cv::Mat> levels(1);
      image.convertTo(levels[0], CV_32F);
      while (levels.back().cols >= 16 && levels.back().rows >= 16) {
        cv::Mat smaller;
        cv::pyrDown(levels.back(), smaller);
        levels.push_back(smaller);
      }
      pyramids_.push_back(std::move(levels));
    }
  }

  int count() const { return static_cast<int>(pyramids_.size()); }

  /// Trilinear sample at level-0 texel coordinates (x, y), with a footprint of `footprint`
  /// texels per pixel.
  float sample(int texture, double x, double y, double footprint) const {
    const std::vector<cv::Mat>& levels = pyramids_[texture];
    const double level = std::clamp(std::log2(std::max(footprint, 1.0)), 0.0,
                                    static_cast<double>(levels.size() - 1));
    const int lower = static_cast<int>(level);
    const double fraction = level - lower;
    const float a = at_level(levels[lower], lower, x, y);
    if (fraction < 1e-3 || lower + 1 >= static_cast<int>(levels.size())) return a;
    const float b = at_level(levels[lower + 1], lower + 1, x, y);
    return static_cast<float>((1.0 - fraction) * a + fraction * b);
  }

 private:
  /// Bilinear sample of pyramid level `level` at level-0 texel coordinates (x, y). cv::pyrDown
  /// centres texel i of a level on texel 2i of the level below, so texel i of level L sits on
  /// level-0 texel 2^L i: level-0 coordinates map to (x - 0.5) / 2^L + 0.5 there (texel centres
  /// at integer + 0.5 on every level). Taking x / 2^L instead would shift level L by
  /// (2^L - 1) / 2 level-0 texels, a shift that changes as a surface's distance moves the
  /// sample between levels: the texture would slide on the surface by up to half a pixel.
  static float at_level(const cv::Mat& image, int level, double x, double y) {
    const double scale = 1.0 / static_cast<double>(1 << level);
    return bilinear(image, (x - 0.5) * scale + 0.5, (y - 0.5) * scale + 0.5);
  }

  static float bilinear(const cv::Mat& image, double x, double y) {
    // Texel centres at integer + 0.5.
    x -= 0.5;
    y -= 0.5;
    const double fx = std::floor(x), fy = std::floor(y);
    const int x0 = static_cast<int>(fx), y0 = static_cast<int>(fy);
    const float ax = static_cast<float>(x - fx), ay = static_cast<float>(y - fy);
    const int c0 = mirror(x0, image.cols), c1 = mirror(x0 + 1, image.cols);
    const float* row0 = image.ptr<float>(mirror(y0, image.rows));
    const float* row1 = image.ptr<float>(mirror(y0 + 1, image.rows));
    const float top = row0[c0] + ax * (row0[c1] - row0[c0]);
    const float bottom = row1[c0] + ax * (row1[c1] - row1[c0]);
    return top + ay * (bottom - top);
  }

  std::vector<std::vector<cv::Mat>> pyramids_;
};

// -------------------------------------------------------------------------------------------------

std::vector<std::string> RenderOptions::validate() const {
  std::vector<std::string> problems;
  if (width < 64 || width > 8192) problems.push_back("--render-width: must be in [64, 8192]");
  if (height < 64 || height > 8192) problems.push_back("--render-height: must be in [64, 8192]");
  if (!(image_noise >= 0.0 && image_noise <= 50.0)) {
    problems.push_back("--render-noise: must be in [0, 50]");
  }
  if (!(object_size > 0.0 && object_size <= 5.0)) {
    problems.push_back("--render-object-size: must be in (0, 5]");
  }
  if (!(pillar_density >= 0.0 && pillar_density <= 20.0)) {
    problems.push_back("--render-pillars: must be in [0, 20]");
  }
  if (supersampling < 1 || supersampling > 8) {
    problems.push_back("--render-supersampling: must be in [1, 8]");
  }
  if (!(frame_rate > 0.0)) problems.push_back("frame rate must be > 0");
  return problems;
}

StereoCamera render_camera(const StereoCamera& simulated, double horizontal_fov_degrees,
                           const RenderOptions& options) {
  StereoCamera camera = simulated;
  const double focal =
      0.5 * options.width / std::tan(0.5 * horizontal_fov_degrees * std::numbers::pi / 180.0);
  camera.K << focal, 0.0, 0.5 * (options.width - 1), 0.0, focal, 0.5 * (options.height - 1), 0.0,
      0.0, 1.0;
  return camera;
}

std::vector<Eigen::Vector3d> TexturedWorld::Cube::corners() const {
  std::vector<Eigen::Vector3d> points;
  const Eigen::Matrix3d rotation = yaw_rotation(yaw);
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d sign((corner & 1) ? 1.0 : -1.0, (corner & 2) ? 1.0 : -1.0,
                               (corner & 4) ? 1.0 : -1.0);
    points.push_back(centre + rotation * (half_size * sign));
  }
  return points;
}

TexturedWorld::TexturedWorld(const fs::path& texture_folder)
    : textures_(std::make_unique<Textures>(texture_folder)) {}
TexturedWorld::TexturedWorld() = default;
TexturedWorld::~TexturedWorld() = default;
TexturedWorld::TexturedWorld(TexturedWorld&&) noexcept = default;
TexturedWorld& TexturedWorld::operator=(TexturedWorld&&) noexcept = default;

int TexturedWorld::texture_count() const { return textures_ ? textures_->count() : 0; }

void TexturedWorld::add_quad(const Quad& quad) { quads_.push_back(quad); }

void TexturedWorld::add_box(const Eigen::Vector3d& centre, const Eigen::Vector3d& half_extent,
                            double yaw, const Quad& style, std::uint64_t seed) {
  const Eigen::Matrix3d rotation = yaw_rotation(yaw);
  const Eigen::Vector3d x = rotation.col(0) * half_extent.x();
  const Eigen::Vector3d y = rotation.col(1) * half_extent.y();
  const Eigen::Vector3d z = rotation.col(2) * half_extent.z();
  Uniform uniform(seed);
  const int textures = std::max(texture_count(), 1);
  const auto face = [&](const Eigen::Vector3d& corner, const Eigen::Vector3d& u,
                        const Eigen::Vector3d& v) {
    Quad quad = style;
    quad.corner = corner;
    quad.edge_u = u;
    quad.edge_v = v;
    quad.texture = static_cast<int>(uniform() * textures) % textures;
    quad.texture_offset = Eigen::Vector2d{uniform(0.0, 2000.0), uniform(0.0, 2000.0)};  // braces: in order
    quad.gain = uniform(0.6, 1.2);
    quads_.push_back(quad);
  };
  const Eigen::Vector3d c = centre;
  face(c - x - y - z, 2 * x, 2 * z);  // -y side
  face(c - x + y - z, 2 * x, 2 * z);  // +y side
  face(c - x - y - z, 2 * y, 2 * z);  // -x side
  face(c + x - y - z, 2 * y, 2 * z);  // +x side
  face(c - x - y + z, 2 * x, 2 * y);  // top
  face(c - x - y - z, 2 * x, 2 * y);  // bottom
}

void TexturedWorld::add_object_cube(const Cube& cube, const Quad& style, std::uint64_t seed) {
  Quad object_style = style;
  object_style.object = cube.id;
  add_box(cube.centre, Eigen::Vector3d::Constant(cube.half_size), cube.yaw, object_style, seed);
  cubes_.push_back(cube);
}

std::optional<TexturedWorld::Hit> TexturedWorld::cast(const Eigen::Vector3d& origin,
                                                      const Eigen::Vector3d& direction) const {
  std::optional<Hit> best;
  for (std::size_t index = 0; index < quads_.size(); ++index) {
    const Quad& quad = quads_[index];
    const Eigen::Vector3d normal = quad.edge_u.cross(quad.edge_v);
    const double denominator = normal.dot(direction);
    if (std::abs(denominator) < 1e-15) continue;
    const double distance = normal.dot(quad.corner - origin) / denominator;
    if (distance <= 1e-9 || (best && distance >= best->distance)) continue;
    const Eigen::Vector3d relative = origin + distance * direction - quad.corner;
    const double s = relative.dot(quad.edge_u) / quad.edge_u.squaredNorm();
    const double t = relative.dot(quad.edge_v) / quad.edge_v.squaredNorm();
    if (s < 0.0 || s > 1.0 || t < 0.0 || t > 1.0) continue;
    best = Hit{distance, static_cast<int>(index)};
  }
  return best;
}

std::vector<std::uint8_t> TexturedWorld::render(const Eigen::Matrix3d& K,
                                                const Eigen::Isometry3d& T_world_camera, int width,
                                                int height, double noise_sigma,
                                                std::uint64_t noise_seed, int supersampling) const {
  if (!textures_) throw std::logic_error("TexturedWorld::render: the world has no textures");
  if (supersampling < 1) throw std::invalid_argument("TexturedWorld::render: supersampling < 1");
  const std::size_t pixels = static_cast<std::size_t>(width) * height;
  std::vector<float> depth(pixels, std::numeric_limits<float>::infinity());
  std::vector<int> hit_quad(pixels, -1);
  std::vector<float> hit_s(pixels), hit_t(pixels);
  const Eigen::Isometry3d T_camera_world = T_world_camera.inverse();
  const double fx = K(0, 0), fy = K(1, 1), cx = K(0, 2), cy = K(1, 2);

  // Every quad in the camera's frame: its plane and the scales of its edge coordinates, for the
  // visibility pass and the samples of the shading pass.
  struct CameraQuad {
    Eigen::Vector3d corner, u, v, normal;
    double plane = 0.0, u_scale = 0.0, v_scale = 0.0;
  };
  std::vector<CameraQuad> in_camera;
  in_camera.reserve(quads_.size());
  for (const Quad& quad : quads_) {
    CameraQuad q;
    q.corner = T_camera_world * quad.corner;
    q.u = T_camera_world.linear() * quad.edge_u;
    q.v = T_camera_world.linear() * quad.edge_v;
    q.normal = q.u.cross(q.v);
    q.plane = q.normal.dot(q.corner);
    q.u_scale = 1.0 / q.u.squaredNorm();
    q.v_scale = 1.0 / q.v.squaredNorm();
    in_camera.push_back(q);
  }

  // 1. Visibility: each quad's screen box, a ray per pixel, nearest hit wins.
  for (std::size_t index = 0; index < quads_.size(); ++index) {
    const auto& [corner, u, v, normal, plane, u_scale, v_scale] = in_camera[index];
    // Clip the rectangle against the near plane, then bound its projection.
    const std::array<Eigen::Vector3d, 4> polygon{corner, corner + u, corner + u + v, corner + v};
    std::vector<Eigen::Vector3d> clipped;
    for (std::size_t i = 0; i < 4; ++i) {
      const Eigen::Vector3d& a = polygon[i];
      const Eigen::Vector3d& b = polygon[(i + 1) % 4];
      const bool a_in = a.z() >= kNearPlane, b_in = b.z() >= kNearPlane;
      if (a_in) clipped.push_back(a);
      if (a_in != b_in) clipped.push_back(a + (kNearPlane - a.z()) / (b.z() - a.z()) * (b - a));
    }
    if (clipped.empty()) continue;
    double u_min = std::numeric_limits<double>::infinity(), u_max = -u_min, v_min = u_min,
           v_max = -u_min;
    for (const Eigen::Vector3d& point : clipped) {
      const double pu = fx * point.x() / point.z() + cx, pv = fy * point.y() / point.z() + cy;
      u_min = std::min(u_min, pu);
      u_max = std::max(u_max, pu);
      v_min = std::min(v_min, pv);
      v_max = std::max(v_max, pv);
    }
    const int column_begin = std::max(0, static_cast<int>(std::floor(u_min)));
    const int column_end = std::min(width - 1, static_cast<int>(std::ceil(u_max)));
    const int row_begin = std::max(0, static_cast<int>(std::floor(v_min)));
    const int row_end = std::min(height - 1, static_cast<int>(std::ceil(v_max)));
    if (column_begin > column_end || row_begin > row_end) continue;
    for (int row = row_begin; row <= row_end; ++row) {
      const double ray_y = (row - cy) / fy;
      for (int column = column_begin; column <= column_end; ++column) {
        const Eigen::Vector3d ray((column - cx) / fx, ray_y, 1.0);
        const double denominator = normal.dot(ray);
        if (std::abs(denominator) < 1e-15) continue;
        const double z = plane / denominator;
        const std::size_t pixel = static_cast<std::size_t>(row) * width + column;
        if (z < kNearPlane || z >= depth[pixel]) continue;
        const Eigen::Vector3d relative = z * ray - corner;
        const double s = relative.dot(u) * u_scale, t = relative.dot(v) * v_scale;
        if (s < 0.0 || s > 1.0 || t < 0.0 || t > 1.0) continue;
        depth[pixel] = static_cast<float>(z);
        hit_quad[pixel] = static_cast<int>(index);
        hit_s[pixel] = static_cast<float>(s);
        hit_t[pixel] = static_cast<float>(t);
      }
    }
  }

  // 2. Shading: trilinear texture lookup with a footprint from depth and obliquity, gain, noise;
  //    with supersampling, the mean of samples spread over the pixel, each on the plane of the
  //    quad its centre sees (a pixel on a quad's edge samples that quad's texture beyond it).
  std::vector<std::uint8_t> image(pixels, 0);
  const NoiseTable& noise = noise_table();
  for (int row = 0; row < height; ++row) {
    for (int column = 0; column < width; ++column) {
      const std::size_t pixel = static_cast<std::size_t>(row) * width + column;
      double value = 90.0;
      if (hit_quad[pixel] >= 0) {
        const Quad& quad = quads_[hit_quad[pixel]];
        const Eigen::Vector3d ray((column - cx) / fx, (row - cy) / fy, 1.0);
        const Eigen::Vector3d normal =
            (T_camera_world.linear() * quad.edge_u.cross(quad.edge_v)).normalized();
        const double cosine = std::max(std::abs(normal.dot(ray.normalized())), 0.05);
        const double metres_per_pixel = depth[pixel] * ray.norm() / (0.5 * (fx + fy));
        const double footprint = quad.texels_per_metre * metres_per_pixel / std::sqrt(cosine);
        const double texels_u = quad.edge_u.norm() * quad.texels_per_metre;
        const double texels_v = quad.edge_v.norm() * quad.texels_per_metre;
        if (supersampling == 1) {
          const double x = quad.texture_offset.x() + hit_s[pixel] * texels_u;
          const double y = quad.texture_offset.y() + hit_t[pixel] * texels_v;
          value = quad.gain * textures_->sample(quad.texture, x, y, footprint);
        } else {
          const CameraQuad& q = in_camera[hit_quad[pixel]];
          double sum = 0.0;
          for (int a = 0; a < supersampling; ++a) {
            for (int b = 0; b < supersampling; ++b) {
              const Eigen::Vector3d sub((column + (a + 0.5) / supersampling - 0.5 - cx) / fx,
                                        (row + (b + 0.5) / supersampling - 0.5 - cy) / fy, 1.0);
              const Eigen::Vector3d relative = q.plane / q.normal.dot(sub) * sub - q.corner;
              const double x = quad.texture_offset.x() + relative.dot(q.u) * q.u_scale * texels_u;
              const double y = quad.texture_offset.y() + relative.dot(q.v) * q.v_scale * texels_v;
              sum += textures_->sample(quad.texture, x, y, footprint / supersampling);
            }
          }
          value = quad.gain * sum / (supersampling * supersampling);
        }
      }
      if (noise_sigma > 0.0) value += noise_sigma * noise.at(noise_seed, pixel);
      image[pixel] = static_cast<std::uint8_t>(std::clamp(std::lround(value), 0L, 255L));
    }
  }
  return image;
}

// -------------------------------------------------------------------------------------------------

TexturedWorld build_world(const dataset::Dataset& simulated, const RenderOptions& options,
                          std::uint64_t seed, std::vector<LandmarkId>& removed_objects) {
  TexturedWorld world(options.textures);
  Uniform uniform(splitmix64(seed ^ 0x776f726c64ULL));

  // 1. Extent of every path and object.
  std::vector<Eigen::Vector3d> path_points;
  for (const dataset::RobotData& robot : simulated.robots) {
    for (const Eigen::Isometry3d& pose : robot.groundtruth)
      path_points.push_back(pose.translation());
  }
  Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d high = -low;
  const auto extend = [&](const Eigen::Vector3d& point) {
    low = low.cwiseMin(point);
    high = high.cwiseMax(point);
  };
  for (const Eigen::Vector3d& point : path_points) extend(point);
  if (path_points.empty()) throw std::invalid_argument("build_world: the dataset has no poses");

  // 2. Objects: cubes at the ground-truth positions, unless a path passes through (the camera
  //    would fly into the cube).
  const double half_size = 0.5 * options.object_size;
  const double object_clearance = std::sqrt(3.0) * half_size + 0.5;
  TexturedWorld::Quad object_style;
  object_style.texels_per_metre = 250.0;
  for (const auto& [id, object_position] : simulated.objects_groundtruth) {
    // A named copy: lambdas may not capture structured bindings before C++20 (clang 14).
    const Eigen::Vector3d position = object_position;
    const bool crossed = std::any_of(path_points.begin(), path_points.end(), [&](const auto& p) {
      return (p - position).norm() < object_clearance;
    });
    if (crossed) {
      removed_objects.push_back(id);
      continue;
    }
    extend(position - Eigen::Vector3d::Constant(half_size));
    extend(position + Eigen::Vector3d::Constant(half_size));
    world.add_object_cube({id, position, half_size, uniform(0.0, std::numbers::pi)}, object_style,
                          splitmix64(seed ^ static_cast<std::uint64_t>(id) ^ 0x6f626aULL));
  }

  // 3. The hall: walls 12 m beyond everything, floor and ceiling 2.5 m beyond.
  const double wall_margin = 12.0, floor_margin = 2.5;
  const Eigen::Vector3d hall_low(low.x() - wall_margin, low.y() - wall_margin,
                                 low.z() - floor_margin);
  const Eigen::Vector3d hall_high(high.x() + wall_margin, high.y() + wall_margin,
                                  high.z() + floor_margin);
  TexturedWorld::Quad scenery;
  scenery.texels_per_metre = 60.0;
  const Eigen::Vector3d hall_centre = 0.5 * (hall_low + hall_high);
  const Eigen::Vector3d hall_half = 0.5 * (hall_high - hall_low);
  world.add_box(hall_centre, hall_half, 0.0, scenery, splitmix64(seed ^ 0x68616c6cULL));

  // 4. Pillars from floor to ceiling, clear of the paths (2 m) and of the objects.
  const double floor_area = (hall_high.x() - hall_low.x()) * (hall_high.y() - hall_low.y());
  const int pillars = static_cast<int>(std::round(options.pillar_density * floor_area / 100.0));
  TexturedWorld::Quad pillar_style;
  pillar_style.texels_per_metre = 150.0;
  for (int pillar = 0; pillar < pillars; ++pillar) {
    for (int attempt = 0; attempt < 50; ++attempt) {
      const double half_width = uniform(0.3, 0.8);
      const Eigen::Vector3d centre(uniform(hall_low.x() + 1.0, hall_high.x() - 1.0),
                                   uniform(hall_low.y() + 1.0, hall_high.y() - 1.0),
                                   hall_centre.z());
      const double reach = std::sqrt(2.0) * half_width;
      const auto horizontal = [&](const Eigen::Vector3d& p) {
        return std::hypot(p.x() - centre.x(), p.y() - centre.y());
      };
      const bool near_path =
          std::any_of(path_points.begin(), path_points.end(),
                      [&](const auto& p) { return horizontal(p) < reach + 2.0; });
      const bool near_object = std::any_of(
          world.cubes().begin(), world.cubes().end(),
          [&](const auto& cube) { return horizontal(cube.centre) < reach + 2.0 * half_size; });
      if (near_path || near_object) continue;
      world.add_box(centre, Eigen::Vector3d(half_width, half_width, hall_half.z()),
                    uniform(0.0, std::numbers::pi), pillar_style,
                    splitmix64(seed ^ 0x70696c6cULL ^ static_cast<std::uint64_t>(pillar)));
      break;
    }
  }
  return world;
}

std::string format_world_geometry(const TexturedWorld& world) {
  std::string out = "object,corner_x,corner_y,corner_z,u_x,u_y,u_z,v_x,v_y,v_z\n";
  char line[512];
  for (const TexturedWorld::Quad& quad : world.quads()) {
    std::snprintf(line, sizeof line, "%lld,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n",
                  static_cast<long long>(quad.object), quad.corner.x(), quad.corner.y(),
                  quad.corner.z(), quad.edge_u.x(), quad.edge_u.y(), quad.edge_u.z(),
                  quad.edge_v.x(), quad.edge_v.y(), quad.edge_v.z());
    out += line;
  }
  return out;
}

TexturedWorld read_world_geometry(const fs::path& file) {
  std::ifstream stream(file);
  if (!stream) throw std::runtime_error(file.string() + ": cannot open the world geometry");
  TexturedWorld world;
  std::string line;
  int line_number = 0;
  while (std::getline(stream, line)) {
    ++line_number;
    if (line_number == 1 || line.empty()) continue;
    TexturedWorld::Quad quad;
    long long object = 0;
    double values[9];
    if (std::sscanf(line.c_str(), "%lld,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &object, &values[0],
                    &values[1], &values[2], &values[3], &values[4], &values[5], &values[6],
                    &values[7], &values[8]) != 10) {
      throw std::runtime_error(file.string() + ":" + std::to_string(line_number) +
                               ": expected 10 comma-separated numbers");
    }
    quad.object = object;
    quad.corner = Eigen::Vector3d(values[0], values[1], values[2]);
    quad.edge_u = Eigen::Vector3d(values[3], values[4], values[5]);
    quad.edge_v = Eigen::Vector3d(values[6], values[7], values[8]);
    world.add_quad(quad);
  }
  if (world.quads().empty()) throw std::runtime_error(file.string() + ": no quads");
  return world;
}

void remove_objects(dataset::Dataset& data, const std::vector<LandmarkId>& ids) {
  if (ids.empty()) return;
  const auto removed = [&](LandmarkId id) {
    return std::find(ids.begin(), ids.end(), id) != ids.end();
  };
  for (const LandmarkId id : ids) data.objects_groundtruth.erase(id);
  for (dataset::RobotData& robot : data.robots) {
    for (auto& observations : robot.objects) {
      std::erase_if(observations, [&](const StereoObservation& o) { return removed(o.id); });
    }
  }
}

std::vector<ObjectBox> visible_object_boxes(const TexturedWorld& world, const StereoCamera& camera,
                                            const Eigen::Isometry3d& T_world_body, int width,
                                            int height, double min_depth, double max_depth) {
  const Eigen::Isometry3d T_world_cam0 = T_world_body * camera.T_cam0_body.inverse();
  const Eigen::Isometry3d T_cam0_world = T_world_cam0.inverse();
  std::vector<ObjectBox> boxes;
  for (const TexturedWorld::Cube& cube : world.cubes()) {
    const Eigen::Vector3d centre = T_cam0_world * cube.centre;
    if (centre.z() < min_depth || centre.z() > max_depth) continue;
    ObjectBox box{cube.id, std::numeric_limits<double>::infinity(), 0.0, 0.0, 0.0};
    box.y_min = box.x_min;
    box.x_max = box.y_max = -box.x_min;
    bool in_front = true;
    for (const Eigen::Vector3d& corner : cube.corners()) {
      const Eigen::Vector3d p = T_cam0_world * corner;
      if (p.z() < 0.1) {
        in_front = false;
        break;
      }
      const double u = camera.K(0, 0) * p.x() / p.z() + camera.K(0, 2);
      const double v = camera.K(1, 1) * p.y() / p.z() + camera.K(1, 2);
      box.x_min = std::min(box.x_min, u);
      box.x_max = std::max(box.x_max, u);
      box.y_min = std::min(box.y_min, v);
      box.y_max = std::max(box.y_max, v);
    }
    if (!in_front || box.x_min < 0.0 || box.y_min < 0.0 || box.x_max > width - 1.0 ||
        box.y_max > height - 1.0) {
      continue;
    }
    const Eigen::Vector3d origin = T_world_cam0.translation();
    const auto hit = world.cast(origin, cube.centre - origin);
    if (!hit || world.quads()[hit->quad].object != cube.id) continue;
    boxes.push_back(box);
  }
  std::sort(boxes.begin(), boxes.end(),
            [](const ObjectBox& a, const ObjectBox& b) { return a.id < b.id; });
  return boxes;
}

void write_rendered_sequences(const dataset::Dataset& simulated, const TexturedWorld& world,
                              const StereoCamera& camera, const RenderOptions& options,
                              double min_depth, double max_depth, std::uint64_t seed,
                              const fs::path& out,
                              const std::function<void(long long, long long)>& progress) {
  long long total = 0;
  for (const dataset::RobotData& robot : simulated.robots) total += robot.num_frames();
  std::atomic<long long> done{0};
  std::mutex progress_mutex;
  std::atomic<std::size_t> next_robot{0};
  std::exception_ptr failure;
  std::mutex failure_mutex;

  const auto render_robot = [&](std::size_t position) {
    const dataset::RobotData& robot = simulated.robots[position];
    const fs::path folder = out / dataset::robot_folder_name(static_cast<int>(position));
    fs::create_directories(folder / "image_0");
    fs::create_directories(folder / "image_1");
    std::vector<Eigen::Isometry3d> camera_poses;
    std::string times;
    std::vector<std::vector<frontend::Detection>> detections(robot.num_frames());
    const std::vector<int> png_options{cv::IMWRITE_PNG_COMPRESSION, 1};
    for (int frame = 0; frame < robot.num_frames(); ++frame) {
      const Eigen::Isometry3d T_world_cam0 =
          robot.groundtruth[frame] * camera.T_cam0_body.inverse();
      const Eigen::Isometry3d T_world_cam1 = T_world_cam0 * camera.T_cam0_cam1;
      camera_poses.push_back(T_world_cam0);
      char name[32];
      std::snprintf(name, sizeof name, "%06d.png", frame);
      for (int side = 0; side < 2; ++side) {
        const std::uint64_t noise_seed =
            splitmix64(seed ^ (position << 40) ^ (static_cast<std::uint64_t>(frame) << 1) ^
                       static_cast<std::uint64_t>(side));
        std::vector<std::uint8_t> pixels =
            world.render(camera.K, side == 0 ? T_world_cam0 : T_world_cam1, options.width,
                         options.height, options.image_noise, noise_seed, options.supersampling);
        const cv::Mat image(options.height, options.width, CV_8UC1, pixels.data());
        const fs::path file = folder / (side == 0 ? "image_0" : "image_1") / name;
        if (!cv::imwrite(file.string(), image, png_options)) {
          throw std::runtime_error(file.string() + ": cannot write the image");
        }
      }
      char time[32];
      std::snprintf(time, sizeof time, "%.6e\n", frame / options.frame_rate);
      times += time;
      for (const ObjectBox& box :
           visible_object_boxes(world, camera, robot.groundtruth[frame], options.width,
                                options.height, min_depth, max_depth)) {
        detections[frame].push_back(
            {frame, box.id, "cube", box.x_min, box.y_min, box.x_max, box.y_max});
      }
      const long long count = ++done;
      if (progress) {
        std::lock_guard lock(progress_mutex);
        progress(count, total);
      }
    }
    dataset::write_file_atomically(folder / "calib.txt",
                                   frontend::format_kitti_calibration(camera.K, camera.baseline()));
    dataset::write_file_atomically(folder / "times.txt", times);
    dataset::write_file_atomically(folder / "poses.txt",
                                   dataset::format_trajectory_kitti(camera_poses));
    dataset::write_file_atomically(folder / "detections.csv",
                                   frontend::format_detections(detections));
  };

  dataset::write_file_atomically(out / "world.csv", format_world_geometry(world));
  const std::size_t threads = std::max<std::size_t>(
      1, std::min<std::size_t>(simulated.robots.size(), std::thread::hardware_concurrency()));
  std::vector<std::thread> workers;
  for (std::size_t thread = 0; thread < threads; ++thread) {
    workers.emplace_back([&] {
      for (std::size_t position; (position = next_robot++) < simulated.robots.size();) {
        try {
          render_robot(position);
        } catch (...) {
          std::lock_guard lock(failure_mutex);
          if (!failure) failure = std::current_exception();
        }
      }
    });
  }
  for (std::thread& worker : workers) worker.join();
  if (failure) std::rethrow_exception(failure);
}

}  // namespace concord::sim
