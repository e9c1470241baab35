#!/bin/bash
# Rate-distortion runs behind docs/codecs.md: draco, rangeimage, voxel (+ raw; VSGP and GMM for
# context) on the simulated tunnel and the real Ouster / KITTI samples.
#   REAL=PATH/TO/shared/data/real STORE=/tmp/rd.sqlite [TARGETS="sim ouster kitti"] [CONTEXT=1] bash tools/codecs_rd.sh
#   lwbench leaderboard --store /tmp/rd.sqlite --format md --columns bytes,ratio,range_rmsd,coverage,chamfer,encode_ms,decode_ms
set -euo pipefail
S=${STORE:-/tmp/rd.sqlite}
L=${LWBENCH:-lwbench}
REAL=${REAL:?set REAL to the folder of real samples}
run() {  # $1 = dataset; the rest: dataset options
  ds=$1; shift
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" \
     --codec raw --codec draco --param draco.quantization_bits=11,12,14,16 \
     --codec rangeimage --param rangeimage.step=0.05,0.02,0.01 \
     --codec voxel --param voxel.voxel_size=1.0,0.5,0.2,0.1 >/dev/null
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" \
     --codec rangeimage --param rangeimage.mode=lossless --param rangeimage.refine=beam,none >/dev/null
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" \
     --codec rangeimage --param rangeimage.refine=none \
     --codec voxel --param voxel.encoding=quantized --param voxel.quant_step=0.01 >/dev/null
}
for target in ${TARGETS:-sim ouster kitti}; do
  case $target in
    sim) run sim --frames 5 ;;
    ouster) run "$REAL/ouster_os1-128_seq3" ;;
    kitti) run "$REAL/kitti00_frames0-1" --dataset-param sensor=hdl64e ;;
  esac
done
# VSGP and GMM (other plugins, at their defaults) for context: seconds to minutes per frame,
# so fewer frames, and only when asked (CONTEXT=1).
if [ "${CONTEXT:-0}" = 1 ]; then
  for codec in vsgp gmm; do
    $L run --dataset sim --frames 5 --no-sequence-metrics --store "$S" --codec $codec >/dev/null || true
    $L run --dataset "$REAL/ouster_os1-128_seq3" --frames 1 --no-sequence-metrics --store "$S" \
       --codec $codec >/dev/null || true
    $L run --dataset "$REAL/kitti00_frames0-1" --dataset-param sensor=hdl64e --frames 1 \
       --no-sequence-metrics --store "$S" --codec $codec >/dev/null || true
  done
fi
