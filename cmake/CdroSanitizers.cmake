# CDRO_SANITIZE=ON builds everything (our code and the tests) with AddressSanitizer and
# UndefinedBehaviorSanitizer; any UB report aborts the test that caused it.
if(CDRO_SANITIZE)
  set(_cdro_san -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
  add_compile_options(${_cdro_san})
  add_link_options(${_cdro_san})
endif()
