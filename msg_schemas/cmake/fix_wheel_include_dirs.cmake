# Used only when building against the ROS 2 PyPI wheels (setup.sh passes it with
# -DCMAKE_PROJECT_INCLUDE). The wheels' CMake exports carry the include directories of the
# machine that built them (/opt/python/cp311-cp311/...), which do not exist here. At the end of
# configuration, rewrite those paths on every imported target to this interpreter's Python and
# numpy include directories.
if(NOT SGREG_PYTHON_INCLUDE OR NOT SGREG_NUMPY_INCLUDE)
  message(FATAL_ERROR "fix_wheel_include_dirs.cmake needs SGREG_PYTHON_INCLUDE and SGREG_NUMPY_INCLUDE")
endif()

function(sgreg_fix_wheel_include_dirs)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_t IN LISTS _targets)
    get_target_property(_dirs ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(_dirs AND "${_dirs}" MATCHES "/opt/python/cp")
      list(TRANSFORM _dirs REPLACE "^/opt/python/cp[^/]*/lib/python[^/]*/site-packages/numpy/.*include$" "${SGREG_NUMPY_INCLUDE}")
      list(TRANSFORM _dirs REPLACE "^/opt/python/cp[^/]*/include/python[0-9.]*$" "${SGREG_PYTHON_INCLUDE}")
      list(REMOVE_DUPLICATES _dirs)
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_dirs}")
    endif()
  endforeach()
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL sgreg_fix_wheel_include_dirs)
