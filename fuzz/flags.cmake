# Included by the top-level CMakeLists.txt when ZSCULPT_BUILD_FUZZERS is ON, before any
# library is defined: every library gets libFuzzer's coverage instrumentation and
# AddressSanitizer + UndefinedBehaviorSanitizer (UB aborts, so the fuzzer sees it).
if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  message(FATAL_ERROR "ZSCULPT_BUILD_FUZZERS needs clang: configure with CC=clang CXX=clang++ "
                      "(Debian: apt-get install clang libclang-rt-14-dev libomp-dev)")
endif()
add_compile_options(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined
                    -fno-omit-frame-pointer -g)
add_link_options(-fsanitize=address,undefined)
