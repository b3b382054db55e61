# Finds the OpenCV modules Concord uses without the full libopencv-dev package (which alone ships
# OpenCVConfig.cmake and pulls in every module): core, imgproc and imgcodecs (plots, images), and
# for the stereo front-end (frontend/) features2d (FAST), video (pyramidal KLT) and calib3d
# (undistortion, stereo rectification, PnP, RANSAC).
# Defines one imported target opencv_<module> per module.
find_path(CONCORD_OPENCV_INCLUDE_DIR opencv2/core.hpp PATH_SUFFIXES opencv4 REQUIRED)
foreach(module core imgproc imgcodecs features2d video calib3d)
  find_library(CONCORD_OPENCV_${module}_LIBRARY opencv_${module} REQUIRED)
  if(NOT TARGET opencv_${module})
    add_library(opencv_${module} UNKNOWN IMPORTED)
    set_target_properties(opencv_${module} PROPERTIES
      IMPORTED_LOCATION "${CONCORD_OPENCV_${module}_LIBRARY}"
      INTERFACE_INCLUDE_DIRECTORIES "${CONCORD_OPENCV_INCLUDE_DIR}")
  endif()
endforeach()
message(STATUS "OpenCV modules: ${CONCORD_OPENCV_core_LIBRARY}, imgproc, imgcodecs, features2d, "
               "video, calib3d")
