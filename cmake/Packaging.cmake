# `cpack -G DEB` (from the build directory) makes depthfuse_<version>_<arch>.deb: the binaries,
# the systemd units, the udev rule, the sysctl drop-in, sysusers/tmpfiles entries and the default
# configuration /etc/depthfuse/depthfuse.toml (a conffile). It is what a rig is flashed with; see
# docs/deployment.md. tests/deploy/test_package.sh builds it and checks its contents.
#
# The package installs below /usr whatever CMAKE_INSTALL_PREFIX is: CPack reruns the install
# rules with the prefix /usr, and the units are written for that prefix at install time.

# --- libraries no Debian package provides --------------------------------------------------------
# libfreenect2 (the Kinect V2 driver) is installed from source, usually in /usr/local
# (docs/kinect2.md). A rig must not need that: every shared library the binaries load from outside
# the system library directories is installed with them in <prefix>/lib/depthfuse, and the
# binaries look there first (RUNPATH $ORIGIN/../lib/depthfuse). Their own dependencies (libusb,
# libturbojpeg) are Debian packages and go into Depends like any other.
set(_df_executables "")
foreach(_target depthfuse depthfuse-capture depthfuse-fusion depthfuse-monitor)
  if(TARGET ${_target})
    list(APPEND _df_executables "$<TARGET_FILE:${_target}>")
    if(TARGET depthfuse_kinect2)
      set_property(TARGET ${_target} APPEND PROPERTY INSTALL_RPATH "$ORIGIN/../lib/depthfuse")
    endif()
  endif()
endforeach()
if(_df_executables)
  install(CODE "
    file(GET_RUNTIME_DEPENDENCIES
      EXECUTABLES ${_df_executables}
      RESOLVED_DEPENDENCIES_VAR _df_resolved
      UNRESOLVED_DEPENDENCIES_VAR _df_unresolved
      POST_EXCLUDE_REGEXES \"^/(usr/)?lib(32|64|x32)?/\")
    if(_df_unresolved)
      message(FATAL_ERROR \"depthfuse binaries need libraries the loader cannot find: \${_df_unresolved}\")
    endif()
    foreach(_df_lib IN LISTS _df_resolved)
      message(STATUS \"Bundling \${_df_lib} (no Debian package provides it)\")
      file(INSTALL \"\${_df_lib}\" DESTINATION \"\${CMAKE_INSTALL_PREFIX}/lib/depthfuse\"
           TYPE SHARED_LIBRARY FOLLOW_SYMLINK_CHAIN)
    endforeach()
  ")
endif()

# --- the package -------------------------------------------------------------------------------
set(CPACK_GENERATOR "DEB" CACHE STRING "CPack generators (cpack -G overrides)")
set(CPACK_PACKAGE_NAME "depthfuse")
set(CPACK_PACKAGE_VENDOR "depthfuse")
set(CPACK_PACKAGE_VERSION "${PROJECT_VERSION}")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "Kinect V2 scanning appliance: live depth map fusion")
set(CPACK_PACKAGE_DESCRIPTION
  "depthfuse turns a Kinect V2 into an unattended 3-D scanner. A capture daemon publishes depth\n"
  "frames on LCM, a fusion daemon fuses them frame by frame into a non-redundant point cloud\n"
  "(Ylimaki et al., ICPR 2018) with pose refinement, bounded memory and SQLite checkpoints, and a\n"
  "monitor reports the appliance's status. Includes the systemd units, the udev rule for the\n"
  "Kinect V2, the LCM multicast route and socket buffer settings, and the depthfuse tool.")
string(REPLACE ";" "" CPACK_PACKAGE_DESCRIPTION "${CPACK_PACKAGE_DESCRIPTION}")
set(CPACK_PACKAGING_INSTALL_PREFIX "/usr")
set(CPACK_PACKAGE_CONTACT "depthfuse maintainers <maintainers@depthfuse.invalid>")

set(CPACK_DEBIAN_PACKAGE_NAME "depthfuse")
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)  # depthfuse_<version>-<release>_<arch>.deb
set(CPACK_DEBIAN_PACKAGE_RELEASE "1")
set(CPACK_DEBIAN_PACKAGE_MAINTAINER "${CPACK_PACKAGE_CONTACT}")
set(CPACK_DEBIAN_PACKAGE_SECTION "science")
set(CPACK_DEBIAN_PACKAGE_PRIORITY "optional")
# The binaries are stripped; their symbols go to depthfuse-dbgsym_<version>_<arch>.ddeb (install
# it next to the package to read a rig's core dumps with gdb).
set(CPACK_DEBIAN_DEBUGINFO_PACKAGE ON)
# The libraries the binaries link come from dpkg-shlibdeps (package dpkg-dev); these are what
# the scripts and units need: systemd (sysusers, tmpfiles, systemctl, the units themselves) and
# ip for depthfuse-lcm-route.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_DEPENDS "systemd (>= 247), iproute2")
# udev applies the Kinect rule; lcm-spy and lcm-logger (liblcm-bin) are handy for field work.
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "udev")
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "liblcm-bin")

# conffiles: dpkg keeps a rig's edited configuration across upgrades and asks before replacing.
set(_deb_control_dir "${CMAKE_BINARY_DIR}/cpack-deb-control")
file(MAKE_DIRECTORY "${_deb_control_dir}")
file(WRITE "${_deb_control_dir}/conffiles" "/etc/depthfuse/depthfuse.toml\n")
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA "${_deb_control_dir}/conffiles")
if(DEPTHFUSE_DEB_SCRIPTS)
  list(APPEND CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA ${DEPTHFUSE_DEB_SCRIPTS})
endif()
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)

# Only what the install rules put there: no stray build files.
set(CPACK_SOURCE_IGNORE_FILES "/build.*/;/out/;/\\\\.git/")

include(CPack)
