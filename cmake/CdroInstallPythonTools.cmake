# Run by `cmake --install` (install(SCRIPT) in CdroInstall.cmake, after the CDRO_TOOLS_* and
# CDRO_DIRS_* were set): the Python tools' environment and commands, for the prefix in effect at
# install time and under $DESTDIR (cmake/cdro_install_tools.py). What it wrote joins
# install_manifest.txt like every other installed file.
foreach(dir BINDIR TOOLS_VENVDIR)
  if(IS_ABSOLUTE "${CDRO_DIRS_${dir}}")
    set(CDRO_FULL_${dir} "${CDRO_DIRS_${dir}}")
  else()
    set(CDRO_FULL_${dir} "${CMAKE_INSTALL_PREFIX}/${CDRO_DIRS_${dir}}")
  endif()
endforeach()
message(STATUS "Installing: $ENV{DESTDIR}${CDRO_FULL_TOOLS_VENVDIR} (the Python tools, with links in "
               "$ENV{DESTDIR}${CDRO_FULL_BINDIR})")
execute_process(
  COMMAND "${CDRO_TOOLS_PYTHON}" "${CDRO_TOOLS_INSTALLER}" --source "${CDRO_TOOLS_SOURCE}"
          --venv "${CDRO_FULL_TOOLS_VENVDIR}" --bindir "${CDRO_FULL_BINDIR}" --destdir "$ENV{DESTDIR}"
          --manifest "${CDRO_TOOLS_MANIFEST}"
  RESULT_VARIABLE status)
if(NOT status EQUAL 0)
  message(FATAL_ERROR "installing the Python tools failed (${status}); -DCDRO_INSTALL_PYTHON_TOOLS=OFF "
                      "leaves them out, CDRO_TOOLS_PYTHON names the interpreter")
endif()
file(STRINGS "${CDRO_TOOLS_MANIFEST}" installed)
list(APPEND CMAKE_INSTALL_MANIFEST_FILES ${installed})
