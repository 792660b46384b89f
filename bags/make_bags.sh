#!/usr/bin/env bash
# Regenerates the shipped bags from synthetic scenes (deterministic: fixed seeds).
#   source env/activate && bags/make_bags.sh
set -euo pipefail
cd "$(dirname "$0")"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
make_one() {  # name kind rooms scene_seed bag_seed extra-args...
  local name=$1 kind=$2 rooms=$3 scene_seed=$4 bag_seed=$5; shift 5
  sgreg synth "$tmp/$name" --kind "$kind" --rooms "$rooms" --seed "$scene_seed" > /dev/null
  rm -rf "$name"
  sgreg make-bag "$tmp/$name" --out "$name" --seed "$bag_seed" --speed 0.3 "$@"
}
make_one apartment_opposite    apartment 2 3 1
make_one office_same_direction office    2 5 2 --same-direction
make_one apartment3_opposite   apartment 3 8 3
# four agents on a building floor with runs of identical rooms: 15 cm maps every 3 s keep it small
make_one building_4agents      building  10 5 1 --agents 4 --voxel 0.15 --speed 0.6 --mapping-period 3 \
  --random-start --waypoints 2
