# `cmake --install`: cdro-hostd, its systemd unit, the sysusers.d entry of its user, the udev rule
# of the board, the example configuration and the docs the unit's Documentation= points at
# (docs/deployment.md lists them), and the Python tools (tools/) in a virtual environment of
# their own with their commands linked into bin (component python-tools; off with
# -DCDRO_INSTALL_PYTHON_TOOLS=OFF, for a packager who ships them in a package of their own).
#
# The systemd, sysusers.d and udev directories are under the prefix (lib/..., not the
# multiarch CMAKE_INSTALL_LIBDIR): /usr/lib/... for --prefix /usr, /usr/local/lib/... for the
# default prefix, both of which systemd and udev read. Override them with the cache variables.
set(CMAKE_INSTALL_DOCDIR "share/doc/cdro-slam" CACHE PATH "documentation (DATAROOTDIR/doc/cdro-slam)")
include(GNUInstallDirs)
set(CDRO_SYSTEMD_UNITDIR "lib/systemd/system" CACHE PATH "systemd system units, relative to the prefix")
set(CDRO_SYSUSERSDIR "lib/sysusers.d" CACHE PATH "sysusers.d entries, relative to the prefix")
set(CDRO_UDEV_RULESDIR "lib/udev/rules.d" CACHE PATH "udev rules, relative to the prefix")
set(CDRO_EXAMPLEDIR "${CMAKE_INSTALL_DOCDIR}/examples" CACHE PATH "the example configuration")

# The unit names absolute paths, which `cmake --install --prefix` can change after the
# configuration: it is written at install time (cmake/CdroInstallUnit.cmake), from the prefix
# then in effect.
install(TARGETS cdro-hostd RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
install(CODE "
  set(CDRO_UNIT_TEMPLATE \"${CMAKE_SOURCE_DIR}/config/systemd/cdro-hostd.service.in\")
  set(CDRO_UNIT_BUILD_DIR \"${CMAKE_BINARY_DIR}/install-unit\")
  set(CDRO_DIRS_BINDIR \"${CMAKE_INSTALL_BINDIR}\")
  set(CDRO_DIRS_DOCDIR \"${CMAKE_INSTALL_DOCDIR}\")
  set(CDRO_DIRS_SYSCONFDIR \"${CMAKE_INSTALL_SYSCONFDIR}\")
  set(CDRO_DIRS_SYSTEMD_UNITDIR \"${CDRO_SYSTEMD_UNITDIR}\")
  set(CDRO_DIRS_SYSUSERSDIR \"${CDRO_SYSUSERSDIR}\")
  set(CDRO_DIRS_EXAMPLEDIR \"${CDRO_EXAMPLEDIR}\")
")
install(SCRIPT ${CMAKE_SOURCE_DIR}/cmake/CdroInstallUnit.cmake)
install(FILES ${CMAKE_SOURCE_DIR}/config/systemd/cdro-slam.sysusers DESTINATION ${CDRO_SYSUSERSDIR}
        RENAME cdro-slam.conf)
install(FILES ${CMAKE_SOURCE_DIR}/config/udev/99-cdro-pozyx.rules DESTINATION ${CDRO_UDEV_RULESDIR})
install(FILES ${CMAKE_SOURCE_DIR}/config/cdro-hostd.example.yaml DESTINATION ${CDRO_EXAMPLEDIR})
file(GLOB CDRO_DOC_PAGES CONFIGURE_DEPENDS ${CMAKE_SOURCE_DIR}/docs/*.md)
install(FILES ${CDRO_DOC_PAGES} ${CMAKE_SOURCE_DIR}/README.md ${CMAKE_SOURCE_DIR}/LICENSE
        DESTINATION ${CMAKE_INSTALL_DOCDIR})

# The Python tools: Debian 12 refuses pip into the system's Python (PEP 668), so they get an
# environment under the prefix whose interpreter also sees the system's site-packages (Debian's
# python3-numpy, ...). Nothing is downloaded (cmake/cdro_install_tools.py).
option(CDRO_INSTALL_PYTHON_TOOLS "cmake --install also installs the Python tools (lib/cdro/venv, bin/cdro-*)" ON)
set(CDRO_TOOLS_VENVDIR "lib/cdro/venv" CACHE PATH "the Python tools' virtual environment, relative to the prefix")
set(CDRO_TOOLS_PYTHON "/usr/bin/python3" CACHE FILEPATH
    "the Python the tools' environment is made from; its site-packages provide their dependencies")
if(CDRO_INSTALL_PYTHON_TOOLS)
  install(CODE "
    set(CDRO_TOOLS_PYTHON \"${CDRO_TOOLS_PYTHON}\")
    set(CDRO_TOOLS_INSTALLER \"${CMAKE_SOURCE_DIR}/cmake/cdro_install_tools.py\")
    set(CDRO_TOOLS_SOURCE \"${CMAKE_SOURCE_DIR}/tools\")
    set(CDRO_TOOLS_MANIFEST \"${CMAKE_BINARY_DIR}/install-python-tools.txt\")
    set(CDRO_DIRS_BINDIR \"${CMAKE_INSTALL_BINDIR}\")
    set(CDRO_DIRS_TOOLS_VENVDIR \"${CDRO_TOOLS_VENVDIR}\")
  " COMPONENT python-tools)
  install(SCRIPT ${CMAKE_SOURCE_DIR}/cmake/CdroInstallPythonTools.cmake COMPONENT python-tools)
endif()
