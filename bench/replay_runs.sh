# Sourced by the replay bench scripts (consistency, graphs), after they set `out`: builds
# `concord` (Release) and copies it to $out/concord (rebuilding during a long bench must not
# change or break it), and defines run NAME DATASET ARGS...: one `concord replay` into $out/NAME,
# skipped when its metrics.json is already there (delete the folder to run it again).
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord >/dev/null
cp build/tools/concord "$out/concord"
concord="$out/concord"

run() {  # name dataset args...
  local name=$1 dataset=$2
  shift 2
  [ -f "$out/$name/metrics.json" ] && return 0
  $concord replay --dataset "$dataset" --out "$out/$name" "$@" >"$out/$name.log" 2>&1 ||
    { echo "bench: $name FAILED (see $out/$name.log)" >&2; return 1; }
  echo "bench: $name" >&2
}
