# CDRO_SANITIZE=ON builds everything (our code and the tests) with AddressSanitizer and
# UndefinedBehaviorSanitizer; any UB report aborts the test that caused it.
# -O1 is what the AddressSanitizer documentation recommends: at -O0 the Eigen-heavy engine runs
# ~250x slower than the native build, at -O1 a test suite that exercises it fits the CI budget.
# Assertions stay on (the sanitized build is a Debug build: no NDEBUG).
if(CDRO_SANITIZE)
  set(_cdro_san -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
  add_compile_options(${_cdro_san} -O1)
  add_link_options(${_cdro_san})
endif()
