#include "concord/frontend/frontend.h"

#include <chrono>
#include <ctime>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>

#include "concord/frontend/object_observer.h"
#include "concord/frontend/rectifier.h"
#include "concord/frontend/stereo_tracker.h"

namespace concord::frontend {

namespace {

using Clock = std::chrono::steady_clock;

double milliseconds_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

/// CPU time of the calling thread, milliseconds.
double thread_cpu_milliseconds() {
  timespec time{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &time);
  return 1e3 * static_cast<double>(time.tv_sec) + 1e-6 * static_cast<double>(time.tv_nsec);
}

cv::Mat load_image(const std::filesystem::path& file) {
  cv::Mat image = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
  if (image.empty()) {
    throw FrontendError(file.string() + ": cannot read or decode the image");
  }
  return image;
}

}  // namespace

void set_opencv_threads(int threads) { cv::setNumThreads(threads); }

std::vector<std::string> FrontendOptions::validate() const {
  std::vector<std::string> problems;
  for (const std::string& problem : tracker.validate()) problems.push_back("tracker." + problem);
  for (const std::string& problem : odometry.validate()) problems.push_back("odometry." + problem);
  for (const std::string& problem : objects.validate()) problems.push_back("objects." + problem);
  return problems;
}

class StereoFrontend::Impl {
 public:
  Impl(StereoSequence sequence, const FrontendOptions& options,
       std::vector<std::vector<Detection>> detections, std::unique_ptr<OdometrySource> odometry)
      : sequence_(std::move(sequence)),
        options_(options),
        rectifier_(sequence_.rig),
        tracker_(options.tracker),
        detections_(std::move(detections)),
        odometry_(std::move(odometry)) {
    if (!detections_.empty() && static_cast<int>(detections_.size()) != sequence_.num_frames()) {
      throw FrontendError("detections: " + std::to_string(detections_.size()) +
                          " frames of detections for a sequence of " +
                          std::to_string(sequence_.num_frames()) + " frames");
    }
    if (!odometry_) {
      odometry_ = std::make_unique<StereoVisualOdometry>(rectifier_.camera(), options.odometry);
    }
    for (const std::string& problem : options.objects.validate()) {
      throw FrontendError("invalid object options: objects." + problem);
    }
  }

  FrontendFrame process_next() {
    if (frame_ >= sequence_.num_frames()) {
      throw std::logic_error("StereoFrontend::process_next: the sequence is done");
    }
    const auto start = Clock::now();
    const double start_cpu = thread_cpu_milliseconds();
    FrontendFrame out;
    out.input.frame = frame_;
    out.timestamp = sequence_.timestamps[frame_];

    // 1. Images: load, undistort and rectify.
    auto stage = Clock::now();
    const cv::Mat left_raw = load_image(sequence_.left_images[frame_]);
    const cv::Mat right_raw = load_image(sequence_.right_images[frame_]);
    out.timings.load = milliseconds_since(stage);
    const double loaded_cpu = thread_cpu_milliseconds();
    stage = Clock::now();
    cv::Mat left, right;
    try {
      rectifier_.rectify(left_raw, right_raw, left, right);
    } catch (const FrontendError& error) {
      throw FrontendError(sequence_.left_images[frame_].string() + ": " + error.what());
    }
    out.timings.rectify = milliseconds_since(stage);

    // 2. Tracks.
    stage = Clock::now();
    TrackedFrame tracked = tracker_.track(left, right);
    out.timings.track = milliseconds_since(stage);

    // 3. Motion from the previous frame; its outlier tracks end here.
    stage = Clock::now();
    if (frame_ > 0) {
      out.motion = odometry_->estimate(frame_, previous_tracks_, tracked.observations);
      out.input.T_previous_current = out.motion.T_previous_current;
      if (!out.motion.outliers.empty()) {
        tracker_.drop_tracks(out.motion.outliers);
        remove_tracks(tracked, out.motion.outliers);
      }
    }
    out.timings.odometry = milliseconds_since(stage);

    // 4. Objects.
    stage = Clock::now();
    if (!detections_.empty()) {
      for (const Detection& detection : detections_[frame_]) {
        ++out.detections;
        const ObjectMeasurement measured = observe_object(rectified_box(detection), left, right,
                                                          rectifier_.camera(), options_.objects);
        if (measured.observation) {
          out.input.objects.push_back(*measured.observation);
          out.object_class_names.push_back(detection.class_name);
          ++out.objects_observed;
        }
        out.objects_ambiguous += measured.skipped == ObjectSkip::kAmbiguous ? 1 : 0;
        out.objects_inconsistent += measured.skipped == ObjectSkip::kInconsistent ? 1 : 0;
      }
    }
    out.timings.objects = milliseconds_since(stage);

    out.counts = tracked.counts;
    out.row_noise_sigma = tracked.row_noise_sigma;
    double length_sum = 0.0;
    for (const int length : tracked.track_lengths) length_sum += length;
    out.mean_track_length =
        tracked.track_lengths.empty() ? 0.0 : length_sum / tracked.track_lengths.size();
    out.input.features = tracked.observations;
    out.alignment_variances = std::move(tracked.alignment_variances);
    previous_tracks_ = std::move(tracked.observations);
    ++frame_;
    out.timings.total = milliseconds_since(start);
    const double end_cpu = thread_cpu_milliseconds();
    out.timings.total_cpu = end_cpu - start_cpu;
    out.timings.processing_cpu = end_cpu - loaded_cpu;
    return out;
  }

  /// A detection box in the rectified left image: the bounding box of its corners and edge
  /// midpoints after rectification (the box itself for rectified input).
  Detection rectified_box(const Detection& raw) const {
    Detection box = raw;
    box.x_min = box.y_min = std::numeric_limits<double>::infinity();
    box.x_max = box.y_max = -std::numeric_limits<double>::infinity();
    for (const double x : {raw.x_min, raw.centre_x(), raw.x_max}) {
      for (const double y : {raw.y_min, raw.centre_y(), raw.y_max}) {
        const cv::Point2d point = rectifier_.rectify_left_point({x, y});
        box.x_min = std::min(box.x_min, point.x);
        box.x_max = std::max(box.x_max, point.x);
        box.y_min = std::min(box.y_min, point.y);
        box.y_max = std::max(box.y_max, point.y);
      }
    }
    return box;
  }

  static void remove_tracks(TrackedFrame& tracked, const std::vector<LandmarkId>& ids) {
    std::size_t kept = 0;
    for (std::size_t index = 0; index < tracked.observations.size(); ++index) {
      if (std::find(ids.begin(), ids.end(), tracked.observations[index].id) != ids.end()) continue;
      tracked.observations[kept] = tracked.observations[index];
      tracked.track_lengths[kept] = tracked.track_lengths[index];
      tracked.alignment_variances[kept] = tracked.alignment_variances[index];
      ++kept;
    }
    tracked.observations.resize(kept);
    tracked.track_lengths.resize(kept);
    tracked.alignment_variances.resize(kept);
  }

  StereoSequence sequence_;
  FrontendOptions options_;
  StereoRectifier rectifier_;
  StereoTracker tracker_;
  std::vector<std::vector<Detection>> detections_;
  std::unique_ptr<OdometrySource> odometry_;
  std::vector<StereoObservation> previous_tracks_;
  int frame_ = 0;
};

StereoFrontend::StereoFrontend(StereoSequence sequence, const FrontendOptions& options,
                               std::vector<std::vector<Detection>> detections,
                               std::unique_ptr<OdometrySource> odometry)
    : impl_(std::make_unique<Impl>(std::move(sequence), options, std::move(detections),
                                   std::move(odometry))) {}

StereoFrontend::~StereoFrontend() = default;

const StereoCamera& StereoFrontend::camera() const { return impl_->rectifier_.camera(); }
const StereoSequence& StereoFrontend::sequence() const { return impl_->sequence_; }
int StereoFrontend::num_frames() const { return impl_->sequence_.num_frames(); }
int StereoFrontend::next_frame() const { return impl_->frame_; }
FrontendFrame StereoFrontend::process_next() { return impl_->process_next(); }

}  // namespace concord::frontend
