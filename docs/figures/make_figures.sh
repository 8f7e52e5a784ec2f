#!/usr/bin/env bash
# Regenerate the figures in docs/figures/ (docs/results.md shows them):
#   demo.png    the demo's two repeats (the default scenario, both laws): hbvs report --plot
#   fit.png     the demo's fit: raw against smoothed desired signals (Remark 1)
#   faults.png  the default law with the target hidden from 8 to 10 s and 10 % dropped frames
# Every step is seeded, so the same hbvs gives the same figures. About a minute.
#   usage: docs/figures/make_figures.sh        (from anywhere, with hbvs installed)
set -euo pipefail
figures="$(cd "$(dirname "$0")" && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
hbvs teach -q -o "$work/teach.mcap"
hbvs fit -q "$work/teach.mcap" -o "$work/fit.mcap"
hbvs repeat -q "$work/fit.mcap" --sim -o "$work/lateral.mcap"
hbvs repeat -q "$work/fit.mcap" --sim --law paper -o "$work/paper.mcap"
hbvs repeat -q "$work/fit.mcap" --sim --occlude 8:10 --drop-rate 0.1 -o "$work/faults.mcap"
hbvs report "$work/lateral.mcap" "$work/paper.mcap" --label "lateral gain (k_2 = 400)" --label "paper's law (k_2 = 1)" \
    --plot "$figures/demo.png" --dpi 150 > /dev/null
hbvs report "$work/fit.mcap" --plot "$figures/fit.png" --dpi 150 > /dev/null
hbvs report "$work/faults.mcap" --label "occluded 8-10 s, 10 % frames dropped" \
    --panels position,heading,e1,ebar2,v,w --plot "$figures/faults.png" --dpi 150 > /dev/null
