#!/usr/bin/env bash
# Every stage of README's speed table, ours beside its best peer, alternating
# for ROUNDS rounds in one sitting (take the best of each line over the rounds).
# Needs a release build and the peers' venv (../shared/bench/setup-peers.sh);
# never part of the tests.
#
#   cargo build --release
#   bench/side_by_side.sh [ROUNDS]        # default 3; writes under /tmp/fusegraph-side-by-side
#
# OLD_FUSEGRAPH=path/to/an/older/release/fusegraph adds the main job cold
# (no cache), fully cached and re-run after an ICP parameter, run by that
# build and this one, alternating; the older build
# runs OLD_GRAPH (default graphs/fusion.toml: give the older checkout's own,
# whose ops it knows). Given OLD_GRAPH, this build runs it cold too: the
# same work as the older build's job, without the stages added since.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
fg=target/release/fusegraph
py=${PEERS_PYTHON:-$HOME/.cache/fusegraph-peers/bin/python}
peers=../shared/bench/peers.py
work=${TMPDIR:-/tmp}/fusegraph-side-by-side
[ -x "$fg" ] || { echo "build first: cargo build --release" >&2; exit 2; }
[ -x "$py" ] || { echo "no peers' venv at $py: run ../shared/bench/setup-peers.sh or set PEERS_PYTHON" >&2; exit 2; }
mkdir -p "$work"
[ -d "$work/phantom/mri" ] || "$fg" phantom --out "$work/phantom" >/dev/null 2>&1
[ -f "$work/mri/otsu_mask.nii.gz" ] || "$fg" run graphs/mri.toml --out "$work/mri" >/dev/null 2>&1
series=$work/phantom/mri
echo "# $(date -u +%F) $(nproc) cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
for round in $(seq "$rounds"); do
  echo "## round $round"
  RAYON_NUM_THREADS=1 "$fg" bench marching-cubes --dicom "$series" --repeat 10 | sed 's/^/ours 1 thread: /'
  "$fg" bench marching-cubes --dicom "$series" --repeat 10 | sed 's/^/ours: /'
  "$py" "$peers" --repeat 10 mc "$series" | grep -i vtk
  "$fg" bench otsu "$series" --repeat 5 | sed 's/^/ours: /'
  "$py" "$peers" --repeat 5 otsu "$series"
  "$fg" bench components "$work/mri/otsu_mask.nii.gz" --repeat 5 | sed 's/^/ours: /'
  "$py" bench/sitk_components.py "$work/mri/otsu_mask.nii.gz" --repeat 5
  "$fg" bench icp --points 100000 --iterations 30 --out "$work/icp" | grep -E "ms per iteration" | sed 's/^/ours:/'
  "$py" "$peers" --repeat 3 icp "$work/icp/source.ply" "$work/icp/target.ply" --iters 30
  "$py" "$peers" --repeat 3 icp "$work/icp/source.ply" "$work/icp/target.ply" --iters 30 --plane
  RAYON_NUM_THREADS=1 "$fg" bench stereo-calibration "$work/phantom/calib" --repeat 10 --out "$work/calib" | tail -2 | head -1 | sed 's/^/ours 1 thread: /'
  "$py" bench/opencv_calibrate.py "$work/calib/pairs.csv" --repeat 10 --threads 1 | tail -1 | sed 's/^/opencv 1 thread: /'
  "$fg" bench stereo-calibration "$work/phantom/calib" --repeat 10 --out "$work/calib" | tail -2 | head -1 | sed 's/^/ours: /'
  "$py" bench/opencv_calibrate.py "$work/calib/pairs.csv" --repeat 10 | tail -1 | sed 's/^/opencv: /'
  "$fg" bench camera-calibration ../shared/data/chessboard_mono --repeat 10 --out "$work/mono" | tail -2 | head -1 | sed 's/^/ours, real photos: /'
  "$py" bench/opencv_calibrate.py "$work/mono/views.csv" --repeat 10 | tail -1 | sed 's/^/opencv, real photos: /'
  # small_gicp on the same clouds, one thread and two; ours on one thread too.
  RAYON_NUM_THREADS=1 "$fg" bench icp --points 100000 --iterations 30 --out "$work/icp" | grep -E "ms per iteration" | sed 's/^/ours 1 thread:/'
  "$py" "$peers" --repeat 3 smallgicp "$work/icp/source.ply" "$work/icp/target.ply" --iters 30 --threads 1 | sed 's/^/1 thread: /'
  "$py" "$peers" --repeat 3 smallgicp "$work/icp/source.ply" "$work/icp/target.ply" --iters 30 --threads 2 | sed 's/^/2 threads: /'
  # GICP: small_gicp's converges in about 6 iterations, so both are timed
  # over 7 (and ours over 1, to take its first iteration apart).
  for threads in 1 2; do
    for n in 1 7; do
      RAYON_NUM_THREADS=$threads "$fg" bench icp --points 100000 --iterations $n --out "$work/icp7" | grep -E "Gicp|covariances" | sed "s/^/ours $threads thread(s), $n iterations:/"
    done
    "$py" bench/gicp_peer.py "$work/icp7" --iters 7 --threads $threads
  done
  # SGM: the phantom's 800 x 600 pair (128 disparities), cones and teddy,
  # ours on one thread and two, OpenCV's StereoSGBM (single-threaded) on the
  # very pairs ours wrote.
  RAYON_NUM_THREADS=1 "$fg" bench sgm --repeat 5 --out "$work/sgm" | grep -v 'peer:' | sed 's/^/ours 1 thread: /'
  "$fg" bench sgm --repeat 5 --out "$work/sgm" > "$work/sgm.txt"
  grep -v 'peer:' "$work/sgm.txt" | sed 's/^/ours: /'
  grep 'peer:' "$work/sgm.txt" | sed 's/.*peer: peers.py //' | while read -r args; do
    # shellcheck disable=SC2086
    "$py" "$peers" --repeat 5 $args </dev/null
  done
  if [ -n "${OLD_FUSEGRAPH:-}" ]; then
    for which in old this; do
      if [ "$which" = old ]; then build=$OLD_FUSEGRAPH graph=${OLD_GRAPH:-graphs/fusion.toml}
      else build=$fg graph=graphs/fusion.toml; fi
      rm -rf "$work/main"
      start=$(date +%s%N)
      status=0
      "$build" run "$graph" --no-cache --out "$work/main" >/dev/null 2>&1 || status=$?
      echo "main job cold, $which build ($build $graph): $((($(date +%s%N) - start) / 1000000)) ms, exit $status"
      if [ "$which" = this ] && [ -n "${OLD_GRAPH:-}" ]; then
        # The same work as the older build's job: this build on its graph
        # (the stages added since are not in it).
        rm -rf "$work/main"
        start=$(date +%s%N)
        status=0
        "$build" run "$OLD_GRAPH" --no-cache --out "$work/main" >/dev/null 2>&1 || status=$?
        echo "main job cold, this build on the older build's graph ($OLD_GRAPH): $((($(date +%s%N) - start) / 1000000)) ms, exit $status"
      fi
      # Each build on its own cache (their formats differ), filled once:
      # a fully cached re-run, then one after an ICP parameter changes (a
      # new value each round, so ICP and what follows it run again).
      cache=$work/cache-$which
      [ -d "$cache" ] || "$build" run "$graph" --cache "$cache" --out "$work/main" >/dev/null 2>&1 || true
      # This build also re-runs with the deformable stage off (a9d37ce's
      # graph had none): ICP and what follows it, like for like.
      reruns=(cached "icp.trim_ratio=0.9$round")
      [ "$which" = old ] || reruns+=("icp.trim_ratio=0.8$round deform.mode=rigid")
      for rerun in "${reruns[@]}"; do
        set_args=()
        if [ "$rerun" != cached ]; then
          for setting in $rerun; do set_args+=(--set "$setting"); done
        fi
        start=$(date +%s%N)
        status=0
        "$build" run "$graph" --cache "$cache" --out "$work/main" "${set_args[@]}" >/dev/null 2>&1 || status=$?
        echo "main job re-run ($rerun), $which build: $((($(date +%s%N) - start) / 1000000)) ms, exit $status"
      done
    done
  fi
done
