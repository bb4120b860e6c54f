# Included through CMAKE_PROJECT_INCLUDE only when building against the PyPI
# ROS 2 wheels (the venv underlay); a regular ROS 2 install never loads it.
#
# The message wheels export CMake targets whose INTERFACE_INCLUDE_DIRECTORIES
# name folders of the machine that built the wheels (a manylinux Python and a
# numpy include). CMake refuses to generate with such paths, so once the
# project's directory has been processed, drop the entries that do not exist.
function(_eqhrl_drop_missing_include_dirs)
  get_directory_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" IMPORTED_TARGETS)
  foreach(_target IN LISTS _targets)
    get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_kept "")
    foreach(_dir IN LISTS _dirs)
      if(_dir MATCHES "^\\$<" OR EXISTS "${_dir}")
        list(APPEND _kept "${_dir}")
      endif()
    endforeach()
    set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _eqhrl_drop_missing_include_dirs)
