#!/bin/bash
# The README's RD table against the noise floor: every installed codec at its defaults on the
# simulated tunnel (5 frames; the simulator's 1 cm noise given to the floor, its VLP-16 model
# declares the datasheet's 3 cm) and on KITTI 00 frame 0 (HDL-64E model: 2 cm).
#   REAL=PATH/TO/shared/data/real STORE=/tmp/floor.sqlite bash tools/floor_rd.sh
#   python tools/floor_table.py /tmp/floor.sqlite
set -uo pipefail
S=${STORE:-/tmp/floor.sqlite}
L=${LWBENCH:-lwbench}
REAL=${REAL:?set REAL to the folder of real samples}
CODECS=$($L list --json | python -c "import json,sys; print(' '.join('--codec '+c['name'] for c in json.load(sys.stdin)['codecs']))")
$L run --dataset sim --frames 5 --metric-param floor.sigma=0.01 $CODECS --no-sequence-metrics --store "$S" \
   --timeout 600 >/dev/null
$L run --dataset "$REAL/kitti00_frames0-1" --dataset-param sensor=hdl64e --frames 1 $CODECS --no-sequence-metrics \
   --store "$S" --timeout 600 >/dev/null
