#!/usr/bin/env bash
# The main job on the bundled sample: match the real Middlebury Reindeer pair guided by its (simulated) sparse LiDAR,
# match it unguided for comparison, and evaluate both against the ground truth. Outputs go to out/.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:-out}
mkdir -p "$out"
s=$here/reindeer
riverbed match "$s/left.png" "$s/right.png" --sparse "$s/lidar_5pct.tif" \
    -o "$out/disparity.tif" --color "$out/disparity.png" --overwrite --json > "$out/match.json"
riverbed match "$s/left.png" "$s/right.png" --guide none --min-disp 0 --max-disp 110 \
    -o "$out/disparity_unguided.tif" --color "$out/disparity_unguided.png" --overwrite
echo "riverbed-guided SGM (5 % LiDAR), evaluated on the pixels without LiDAR:"
riverbed evaluate "$out/disparity.tif" "$s/gt.png" --gt-scale 2 --exclude "$s/lidar_5pct.tif" \
    --error-map "$out/errors.png" --overwrite
echo
echo "unguided SGM, same pixels:"
riverbed evaluate "$out/disparity_unguided.tif" "$s/gt.png" --gt-scale 2 --exclude "$s/lidar_5pct.tif"
echo
echo "wrote $out/disparity.tif, $out/disparity.png (preview), $out/errors.png, $out/match.json"
