# Install rules and the Debian package (CPack): `cpack -G DEB` in the build folder writes
# concord_<version>_<arch>.deb. Layout (prefix /usr):
#   /usr/bin/concordd, /usr/bin/concord
#   /usr/lib/systemd/system/concordd@.service   (Type=notify, watchdog, User=concord)
#   /usr/share/concord/examples/                (robot.yaml: a live robot; robot-replay.yaml)
#   /usr/share/concord/sensors/, /usr/share/concord/data/kitti00-300/
#   /usr/share/doc/concord/                     (README.md and docs/*.md)
#   /etc/concord/ (configs and keys, root:concord 0750), /var/lib/concord/ (outputs, concord 0750)
# The maintainer scripts (packaging/debian/) create the system user `concord`.
install(TARGETS concordd concord RUNTIME DESTINATION bin)
install(FILES configs/systemd/concordd@.service DESTINATION lib/systemd/system)
install(FILES packaging/examples/robot.yaml packaging/examples/robot-replay.yaml
              packaging/examples/camera-kitti.json
        DESTINATION share/concord/examples)
install(FILES configs/sensors/kitti-stereo.yaml configs/sensors/sim.yaml
              configs/sensors/datasets.yaml
        DESTINATION share/concord/sensors)
install(DIRECTORY data/kitti00-300 DESTINATION share/concord/data)
file(GLOB CONCORD_DOCS ${PROJECT_SOURCE_DIR}/docs/*.md)
install(FILES README.md ${CONCORD_DOCS} DESTINATION share/doc/concord)
# Folders the package owns outside the prefix (ownership and modes are set by postinst).
install(DIRECTORY DESTINATION /etc/concord)
install(DIRECTORY DESTINATION /var/lib/concord)

set(CPACK_GENERATOR "DEB")
set(CPACK_PACKAGE_NAME "concord")
set(CPACK_PACKAGE_VERSION "${PROJECT_VERSION}")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "Multi-robot object SLAM daemon (concordd) and tools")
set(CPACK_PACKAGE_DESCRIPTION "One concordd per robot estimates its trajectory and an object \
map and agrees on the map with its team by consensus over an authenticated peer-to-peer network; \
concord replays, simulates and evaluates. Runs under systemd (concordd@ROBOT.service, Type=notify \
with a watchdog).")
# A package of a build for a CPU (CONCORD_ARCH, CMakeLists.txt) runs only on such CPUs: it says
# so. Configure with -DCONCORD_ARCH=baseline for a package meant for any machine.
if(CONCORD_MARCH)
  string(APPEND CPACK_PACKAGE_DESCRIPTION " Built for -march=${CONCORD_MARCH}: it runs only on \
CPUs with those instructions.")
  message(STATUS "Concord: the Debian package is built for -march=${CONCORD_MARCH}, not for \
every ${CMAKE_SYSTEM_PROCESSOR} machine (CONCORD_ARCH=baseline for that)")
endif()
set(CPACK_PACKAGE_CONTACT "Concord maintainers <concord@example.invalid>")
set(CPACK_PACKAGING_INSTALL_PREFIX "/usr")
set(CPACK_STRIP_FILES ON)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION "science")
# Library dependencies computed by dpkg-shlibdeps from the binaries.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
    "${PROJECT_SOURCE_DIR}/packaging/debian/postinst;${PROJECT_SOURCE_DIR}/packaging/debian/prerm;${PROJECT_SOURCE_DIR}/packaging/debian/postrm")
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
# gzip: fast to build in CI; the package is a few MB.
set(CPACK_DEBIAN_COMPRESSION_TYPE "gzip")
include(CPack)
