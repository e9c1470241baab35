#!/usr/bin/env bash
# The stream figures of docs/stream.md and the README: the VSGP paper's Fig. 6d on lwbench's
# simulated mine tunnel (VLP-16, 10 m, 4 Hz), raw / gmm / vsgp through five link caps.
# GMM fits on 4,000 points with 20 EM iterations (K = 200, the paper's pair of VSGP M = 500):
# at its defaults it takes ~12 s per scan on a 2-core CPU. Usage: tools/stream_fig6d.sh OUT [extra args]
set -euo pipefail
out=${1:?output folder}
shift
lwbench stream --codec raw --codec gmm --codec vsgp --param gmm.fit_points=4000 --param gmm.max_iter=20 \
  --cap none --cap 2000 --cap 250 --cap 50 --cap 20 --frames 40 --out "$out" "$@"
