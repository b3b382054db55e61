#!/usr/bin/env bash
# Installs what is missing, then runs the whole CI (`.ci/run` calls exactly this):
#   1. Release build (GCC) and the whole test suite;
#   2. clang build with AddressSanitizer + UndefinedBehaviorSanitizer: the whole test suite, and
#      the libFuzzer targets (fuzz/), each run for FUZZ_SECONDS (default 30) from its seed corpus;
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
  fuzz_frame_decoder fuzz_channel fuzz_marginal fuzz_negotiation fuzz_consensus fuzz_http_target
stage "ASan+UBSan tests"
# The Monte-Carlo consistency runs (the first-estimate term's 24 runs and the persistent
# detection error's among them), the archive-mode comparison, the eight-world feature test and
# the two accuracy replays of the repository's slices, and the Monte-Carlo runs of the detection
# offset and displacement states, exercise only the estimator's arithmetic (no input from
# outside the tree) and take minutes under the sanitizers (the first-estimate runs 215 s, near
# ctest's 300 s timeout on a busy machine): they run in Release above.
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
  ctest --test-dir build-asan --output-on-failure --parallel 2 \
  -E '^(MonteCarloNees\..*|Archiving\..*|FirstEstimateNoise\.MakesSeparateRunsLessOverconfidentAtNoCostInAccuracy|PersistentDetectionError\..*|DetectionOffset\.AStateForAnOffsetThatStaysAlongTheTrackKeepsTheObjectHonest|DetectionDisplacement\.AStateForADisplacementInSpaceKeepsTheObjectHonest|FeatureUpdate\.ReducesTheDriftOfBiasedOdometry|TeamReplay\.(Sim15|Kitti00)SliceConsensusAgreesBetterThanSeparate)$'

# Two fuzzers at a time (one per core), each for FUZZ_SECONDS; their reports are printed in turn.
# (libFuzzer's -fork mode would let one fuzzer use both cores, but it exits 0 when a child finds
# a crash.)
fuzz_seconds="${FUZZ_SECONDS:-30}"
fuzz() {  # target: runs one fuzzer on a copy of its seed corpus, its report in build-asan/fuzz
  local corpus
  corpus=$(mktemp -d)
  cp fuzz/corpus/"$1"/* "$corpus"/
  local status=0
  ./build-asan/fuzz/fuzz_"$1" -max_total_time="$fuzz_seconds" -max_len=65536 \
    -print_final_stats=1 "$corpus" > build-asan/fuzz/"$1".log 2>&1 || status=$?
  rm -rf "$corpus"
  return "$status"
}
for group in "frame_decoder channel" "marginal http_target" "negotiation consensus"; do
  read -r -a targets <<< "$group"
  stage "fuzzing ${targets[*]} for ${fuzz_seconds} s"
  pids=()
  for target in "${targets[@]}"; do
    fuzz "$target" & pids+=($!)
  done
  failed=0
  for i in "${!targets[@]}"; do
    wait "${pids[$i]}" || failed=1
    echo "--- fuzz_${targets[$i]}"; tail -n 12 build-asan/fuzz/"${targets[$i]}".log
  done
  if [ "$failed" != 0 ]; then
    for target in "${targets[@]}"; do  # the whole report of a failed fuzzer
      grep -q "ERROR\|BINGO\|crash-\|timeout-\|oom-\|deadly signal" build-asan/fuzz/"$target".log &&
        cat build-asan/fuzz/"$target".log
    done
    echo "a fuzzer failed (reports in build-asan/fuzz)" >&2
    exit 1
  fi
done

stage "TSan build (network, HTTP and daemon tests)"
cmake -S . -B build-tsan "${sanitizer_flags[@]}" -DCONCORD_SANITIZE=thread \
  "-DCONCORD_TEST_GLOB=net_*_test.cc;http_*_test.cc;daemon_*_test.cc"  # concordd under TSan too
cmake --build build-tsan --parallel 2 --target concord_tests concordd
stage "TSan tests"
# The daemon tests below differ from the ones that run here only in the estimator's or the
# association's options (the daemons' threads, sockets and rounds are the same code): they run
# in Release and under ASan+UBSan above, and under TSan would add about 3 minutes.
TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$PWD/scripts/tsan.supp" \
  ctest --test-dir build-tsan --output-on-failure --parallel 2 \
  -E '^(DaemonExchange\.(LockstepWithDetectionOffsetsReproducesTheReplay|LockstepWithDetectionDisplacementsReproducesTheReplay|CompactEventTriggeredSharingReproducesTheReplayWithFewerBytes|LockstepOnARingReproducesTheRingReplay)|DaemonProcess\.DaemonsOverASimulatedRadioReproduceTheRangeLimitedReplay|DaemonAssociation\.ExchangesReproduceTheNegotiatedReplay(WithFrameCorrections)?)$'
stage "all passed"
