# Warnings are errors in our own code, with a deliberate extra set.
# Third-party headers (Eigen, GoogleTest, spdlog, ...) are included as SYSTEM and are exempt.
set(CDRO_C_WARNINGS
  -Wall -Wextra -Wpedantic -Werror
  -Wshadow -Wconversion -Wsign-conversion -Wdouble-promotion
  -Wcast-align -Wfloat-equal -Wswitch-enum -Wundef -Wstrict-prototypes
  -Wmissing-prototypes -Wformat=2)
set(CDRO_CXX_WARNINGS
  -Wall -Wextra -Wpedantic -Werror
  -Wshadow -Wconversion -Wsign-conversion -Wdouble-promotion
  -Wcast-align -Wundef -Wformat=2 -Wnon-virtual-dtor -Woverloaded-virtual)
# gcc 5.4 (avr-gcc) does not know -Wnull-dereference; the host compilers do.
if(NOT CMAKE_SYSTEM_PROCESSOR STREQUAL "avr")
  list(APPEND CDRO_C_WARNINGS -Wnull-dereference)
  list(APPEND CDRO_CXX_WARNINGS -Wnull-dereference)
endif()

# cdro_target_warnings(<target>): apply the project's warning set to one of our targets. Tests,
# benchmarks and the firmware-in-the-loop harness get the same set as the code they exercise:
# a warning that finds a bug finds it in a test too.
function(cdro_target_warnings target)
  target_compile_options(${target} PRIVATE
    $<$<COMPILE_LANGUAGE:C>:${CDRO_C_WARNINGS}>
    $<$<COMPILE_LANGUAGE:CXX>:${CDRO_CXX_WARNINGS}>)
endfunction()
