#pragma once
/// \file
/// Counters of one tracked frame (StereoTracker), shared by the OpenCV-free parts of the
/// front-end's interface.

namespace concord::frontend {

/// What happened to the tracks at one frame.
struct TrackingCounts {
  int previous = 0;           ///< tracks at the start of the frame
  int lost_temporal = 0;      ///< temporal KLT failed or left the image
  int lost_stereo = 0;        ///< stereo KLT failed or left the image
  int rejected_circular = 0;  ///< the loop did not close (tracks) or left-right-left (new ones)
  int rejected_epipolar = 0;  ///< off the row, or disparity out of range
  int rejected_ransac = 0;    ///< temporal RANSAC outliers
  int continued = 0;          ///< tracks that go on
  int detected = 0;           ///< new FAST corners offered (matched in rank order until enough)
  int added = 0;              ///< new tracks
  int reanchored = 0;         ///< anchored tracking: tracks anchored afresh (under a new id)
};

}  // namespace concord::frontend
