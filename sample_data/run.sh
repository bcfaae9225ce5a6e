#!/usr/bin/env bash
# The main job on the bundled sample aerial block: LiDAR (LAZ) -> sparse disparities -> LiDAR-guided matching ->
# point cloud + DSM -> accuracy against the ground truth, with unguided matching alongside for comparison.
# Usage: bash sample_data/run.sh [OUTDIR]   (default: out)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:-out}
b=$here/block
mkdir -p "$out"
step() { printf '\n== %s\n' "$*"; }

step "project: LiDAR -> sparse disparities of the left image"
riverbed project "$b/lidar.laz" "$b/pair.yaml" -o "$out/sparse.tif" --overwrite --json > "$out/project.json"
grep -E '"(kept|lidar_share|window)"' "$out/project.json"

step "match: census + riverbed-guided SGM (and unguided, for comparison)"
riverbed match "$b/left.png" "$b/right.png" --sparse "$out/sparse.tif" -o "$out/disparity.tif" \
    --color "$out/disparity.png" --overwrite --json > "$out/match.json"
grep -E '"(seconds|window|d_min|d_max)"' "$out/match.json"
riverbed match "$b/left.png" "$b/right.png" --sparse "$out/sparse.tif" --guide none \
    -o "$out/disparity_unguided.tif" --color "$out/disparity_unguided.png" --overwrite

step "dsm: triangulate, rasterise (cloud-optimised GeoTIFF), point cloud, hillshade"
riverbed dsm "$out/disparity.tif" "$b/pair.yaml" -o "$out/dsm.tif" --points "$out/points.laz" \
    --hillshade "$out/dsm_hillshade.png" --fill-holes 3 --overwrite --json > "$out/dsm.json"
riverbed dsm "$out/disparity_unguided.tif" "$b/pair.yaml" -o "$out/dsm_unguided.tif" --fill-holes 3 --overwrite

step "evaluate: disparity on the pixels without LiDAR, DSM against the ground-truth DSM"
{
  echo "disparity, riverbed-guided:";  riverbed evaluate "$out/disparity.tif" "$b/gt_disparity.tif" --exclude "$out/sparse.tif" --error-map "$out/disparity_errors.png" --overwrite
  echo; echo "disparity, unguided:";   riverbed evaluate "$out/disparity_unguided.tif" "$b/gt_disparity.tif" --exclude "$out/sparse.tif"
  echo; echo "DSM, riverbed-guided (m):"; riverbed evaluate --dsm "$out/dsm.tif" "$b/gt_dsm.tif" --error-map "$out/dsm_errors.png" --overwrite
  echo; echo "DSM, unguided (m):";        riverbed evaluate --dsm "$out/dsm_unguided.tif" "$b/gt_dsm.tif"
} | tee "$out/accuracy.txt"

step "an older LiDAR (lidar_earlier.laz): its offset, the points the images contradict, what changed since"
riverbed project "$b/lidar_earlier.laz" "$b/pair.yaml" -o "$out/sparse_earlier.tif" --overwrite --json \
    > "$out/project_earlier.json"
riverbed match "$b/left.png" "$b/right.png" --sparse "$out/sparse_earlier.tif" -o "$out/disparity_earlier.tif" \
    --lidar-mask "$out/lidar_mask.png" --overwrite --json > "$out/match_earlier.json"
riverbed dsm "$out/disparity_earlier.tif" "$b/pair.yaml" -o "$out/dsm_earlier.tif" --fill-holes 3 \
    --change-map "$out/change.tif" --sparse "$out/sparse_earlier.tif" --lidar-mask "$out/lidar_mask.png" \
    --overwrite --json > "$out/dsm_earlier.json"
python3 - "$b/scene.json" "$out" <<'PY' | tee "$out/earlier.txt"
import json, sys
truth = json.load(open(sys.argv[1]))["lidar_earlier"]
out = sys.argv[2]
offset = json.load(open(f"{out}/project_earlier.json"))["lidar_offset"]
check = json.load(open(f"{out}/match_earlier.json"))["lidar_check"]
change = json.load(open(f"{out}/dsm_earlier.json"))["change_map"]
print(f"height offset: estimated {offset['vertical_m']:+.2f} m, true {truth['offset_m'][2]:+.2f} m")
print(f"check: {check['outliers']} outliers and {check['changed']} points of {check['regions']} changed regions "
      f"dropped (of {check['points']})")
x0, y0, x1, y1 = truth["removed_building"]["bounds"]
print(f"change map: {change['cells']} cells, median {change['median']:+.2f} m; the building built since: "
      f"{truth['removed_building']['height_m']:.2f} m tall at E {x0:.1f}-{x1:.1f}, N {y0:.1f}-{y1:.1f}")
PY

step "done: $out/ holds sparse.tif, disparity.tif + .png, points.laz, dsm.tif, dsm_hillshade.png, accuracy.txt,
and for the older LiDAR lidar_mask.png, change.tif, earlier.txt"
