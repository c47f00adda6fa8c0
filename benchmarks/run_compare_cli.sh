#!/usr/bin/env bash
# Runs `catgraph compare` (every observation model on one input) on the synthetic world,
# Nordland 32x16 summer->winter in order and shuffled (seed 0), and UJI Wi-Fi month 01 vs 02,
# and writes the printed tables to benchmarks/results/compare_cli.md.
set -euo pipefail
cd "$(dirname "$0")/.."
D=../shared/data
out=benchmarks/results/compare_cli.md
{
  echo "# \`catgraph compare\` on four inputs"
  echo
  echo "Measured at commit \`$(git rev-parse --short HEAD)\`. Each table is the output of the command above it
(the registry's defaults; the filters rank their answers by their score, the posterior log-odds of the
answer's neighbourhood, ±2 mean spacings along the route, which never reads the ground truth or its
tolerance; ms/frame is the method's own time per query frame, difference matrix excluded)."
  run() {
    echo; echo "\`\`\`"; echo "\$ catgraph compare $*"
    catgraph compare "$@" 2>/dev/null; echo "\`\`\`"
  }
  run synthetic:0 synthetic:0
  if [ -d "$D/nordland" ]; then
    run $D/nordland/32x16/summer $D/nordland/32x16/winter --tolerance 2
    run $D/nordland/32x16/summer $D/nordland/32x16/winter --tolerance 2 --shuffle 0
  fi
  if [ -d "$D/uji-lib" ]; then
    run $D/uji-lib/db/01/trn01 $D/uji-lib/db/02/tst01 --tolerance-m 3
  fi
} > "$out"
echo "wrote $out"
