#!/usr/bin/env bash
# Regenerates the README's pictures (docs/pictures/*.png): runs the
# paper-figure scenes, renders their frames (`cleave render`) and keeps one
# frame of each. Usage: docs/pictures.sh (from anywhere; about a minute).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
mkdir -p docs/pictures
picture() { # scene, frame, extra render flags
    ./target/release/cleave run "scenes/$1.toml" --out "out/pictures/$1" > /dev/null
    ./target/release/cleave render "out/pictures/$1" ${3:-} > /dev/null
    cp "out/pictures/$1/frame_$(printf %04d "$2").png" "docs/pictures/$1.png"
    echo "docs/pictures/$1.png"
}
picture bunny_cut 30
picture cube_slice 25
picture random_cube_drop 8 --stress
picture nonconvex_element 10
