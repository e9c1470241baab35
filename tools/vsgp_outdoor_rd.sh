#!/bin/bash
# Issue 19's outdoor figures: VSGP without and with its residual layer, the layer's control
# (predictor=none: no surface) and rangeimage, on the shared KITTI and Ouster frames (the loaders'
# own sensor models) and the simulated tunnel, through `lwbench run` into one store.
#   REAL=PATH/TO/shared/data/real STORE=/tmp/vsgp_rd.sqlite [TARGETS="kitti ouster sim"] bash tools/vsgp_outdoor_rd.sh
#   lwbench leaderboard --store /tmp/vsgp_rd.sqlite --format md \
#       --columns bytes,ratio,range_rmsd,coverage,chamfer,encode_ms,decode_ms
set -euo pipefail
S=${STORE:-/tmp/vsgp_rd.sqlite}
L=${LWBENCH:-lwbench}
REAL=${REAL:?set REAL to the folder of real samples}
TAUS=${TAUS:-0.1,0.25,0.5,1}
run() {  # $1 = dataset; the rest: dataset options
  ds=$1; shift
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" --timeout 600 \
     --codec vsgp --param vsgp.body=q16z --param vsgp.residual=$TAUS >/dev/null
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" --timeout 600 \
     --codec vsgp --param vsgp.body=q16z --param vsgp.residual=$TAUS --param vsgp.num_inducing=300 >/dev/null
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" --timeout 600 \
     --codec vsgp --param vsgp.body=q16z --param vsgp.residual=$TAUS --param vsgp.predictor=none >/dev/null
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" --timeout 600 \
     --codec vsgp --param vsgp.body=q16z --param vsgp.bytes=12000,25000,50000 >/dev/null
  $L run --dataset "$ds" "$@" --no-sequence-metrics --store "$S" --timeout 600 \
     --codec vsgp --codec rangeimage --param rangeimage.step=0.2,0.5,1,2 >/dev/null
}
for target in ${TARGETS:-kitti ouster sim}; do
  case $target in
    kitti) run "$REAL/kitti00_frames0-1" --frames 2 ;;
    ouster) run "$REAL/ouster_os1-128_seq3" --frames 2 ;;
    sim) run sim --frames 5 ;;
  esac
done
