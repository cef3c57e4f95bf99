# CDRO_SANITIZE=ON builds everything (our code and the tests) with AddressSanitizer and
# UndefinedBehaviorSanitizer; any UB report aborts the test that caused it.
# -O1 is what the AddressSanitizer documentation recommends: at -O0 the Eigen-heavy engine tests
# ran 60-80x slower than in the native build (two of them past CTest's 300 s), at -O1 7-9x faster
# than that (the sanitized CTest run: about 3 minutes on 2 cores).
# Assertions stay on (the sanitized build is a Debug build: no NDEBUG).
if(CDRO_SANITIZE)
  set(_cdro_san -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
  add_compile_options(${_cdro_san} -O1)
  add_link_options(${_cdro_san})
endif()
