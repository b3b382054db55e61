#!/usr/bin/env bash
# Installs what is missing, then runs the whole CI (`.ci/run` calls exactly this):
#   1. Release build (GCC) and the whole test suite;
#   2. clang build with AddressSanitizer + UndefinedBehaviorSanitizer: the whole test suite, and
#      the libFuzzer targets (fuzz/), each run for FUZZ_SECONDS (default 45) from its seed corpus;
#   3. clang build with ThreadSanitizer: the network, HTTP and daemon tests.
# Fails if any step fails. SKIP_SANITIZERS=1 runs step 1 only (a quick local check).
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/install-deps.sh
start=$(date +%s)
stage() { echo "=== test.sh: $* ($(( $(date +%s) - start )) s)" >&2; }

stage "Release build"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build --parallel 2
stage "Release tests"
ctest --test-dir build --output-on-failure --parallel 2

if [ "${SKIP_SANITIZERS:-0}" = "1" ]; then
  stage "sanitizers skipped (SKIP_SANITIZERS=1)"
  exit 0
fi

# Sanitizer builds: optimized (-O1) so that the multi-process tests keep their pace, with line
# tables only (stack traces name file and line; full debug information would double the build).
sanitizer_flags=(-G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++
                 "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -gline-tables-only")

stage "ASan+UBSan build (with the fuzzers)"
cmake -S . -B build-asan "${sanitizer_flags[@]}" -DCONCORD_SANITIZE=address,undefined \
  -DCONCORD_BUILD_FUZZERS=ON
# The test suite, the daemon it starts and the fuzzers (not the `concord` tool: no test runs it).
cmake --build build-asan --parallel 2 --target concord_tests concordd \
  fuzz_frame_decoder fuzz_channel fuzz_marginal fuzz_http_target
stage "ASan+UBSan tests"
# The Monte-Carlo consistency runs and the eight-world feature test exercise only the
# estimator's arithmetic on simulated data (no input from outside) and take minutes under the
# sanitizers: they run in Release above.
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
  ctest --test-dir build-asan --output-on-failure --parallel 2 \
  -E '^(MonteCarloNees\..*|FeatureUpdate\.ReducesTheDriftOfBiasedOdometry)$'

fuzz_seconds="${FUZZ_SECONDS:-45}"
for target in frame_decoder channel marginal http_target; do
  stage "fuzzing $target for ${fuzz_seconds} s"
  corpus=$(mktemp -d)
  cp fuzz/corpus/"$target"/* "$corpus"/
  ./build-asan/fuzz/fuzz_"$target" -max_total_time="$fuzz_seconds" -max_len=65536 \
    -print_final_stats=1 "$corpus" 2>&1 | tail -n 12
  rm -rf "$corpus"
done

stage "TSan build (network, HTTP and daemon tests)"
cmake -S . -B build-tsan "${sanitizer_flags[@]}" -DCONCORD_SANITIZE=thread \
  "-DCONCORD_TEST_GLOB=net_*_test.cc;http_*_test.cc;daemon_*_test.cc"  # concordd under TSan too
cmake --build build-tsan --parallel 2 --target concord_tests concordd
stage "TSan tests"
TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$PWD/scripts/tsan.supp" \
  ctest --test-dir build-tsan --output-on-failure --parallel 2
stage "all passed"
