# Runs at install time (install(SCRIPT) from systemd/CMakeLists.txt): writes the units with the
# paths of this installation and installs them. CMAKE_INSTALL_PREFIX is the prefix being
# installed to (CPack sets /usr); file(INSTALL) honours DESTDIR.
# In: DEPTHFUSE_UNIT_SOURCE_DIR, DEPTHFUSE_UNIT_BINARY_DIR, DEPTHFUSE_UNIT_TEMPLATES,
#     DEPTHFUSE_UNIT_BINDIR (relative to the prefix).
set(_units_dir "${DEPTHFUSE_UNIT_BINARY_DIR}/units")
file(MAKE_DIRECTORY "${_units_dir}")
foreach(_template IN LISTS DEPTHFUSE_UNIT_TEMPLATES)
  file(READ "${DEPTHFUSE_UNIT_SOURCE_DIR}/${_template}" _text)
  string(REPLACE "@BINDIR@" "${CMAKE_INSTALL_PREFIX}/${DEPTHFUSE_UNIT_BINDIR}" _text "${_text}")
  string(REPLACE "@LIBEXECDIR@" "${CMAKE_INSTALL_PREFIX}/lib/depthfuse" _text "${_text}")
  string(REPLACE "@DOCDIR@" "${CMAKE_INSTALL_PREFIX}/share/doc/depthfuse" _text "${_text}")
  if(_text MATCHES "@[A-Z_]+@")
    message(FATAL_ERROR "${_template}: unknown placeholder ${CMAKE_MATCH_0}")
  endif()
  string(REGEX REPLACE "\\.in$" "" _unit "${_template}")
  file(WRITE "${_units_dir}/${_unit}" "${_text}")
  file(INSTALL "${_units_dir}/${_unit}"
       DESTINATION "${CMAKE_INSTALL_PREFIX}/lib/systemd/system"
       FILE_PERMISSIONS OWNER_READ OWNER_WRITE GROUP_READ WORLD_READ)
endforeach()
