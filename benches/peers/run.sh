#!/usr/bin/env bash
# The peer comparison: cleave against scikit-fem, pbatoolkit and CHOLMOD
# (scikit-sparse) on the same bunny mesh and matrix; prints one table.
#
#   benches/peers/run.sh [MESH]      (default assets/bunny_100k.mesh)
#
# Makes a virtual environment in target/peers-venv with pinned versions from
# PyPI. scikit-sparse builds against the system's CHOLMOD: on Debian 12,
# `apt-get install libsuitesparse-dev libopenblas0-pthread` (SuiteSparse 5,
# hence scikit-sparse 0.4.16; 0.5 needs SuiteSparse 7; with the reference
# BLAS, CHOLMOD's numeric factorisation runs about ten times slower). Not
# part of CI.
set -euo pipefail
cd "$(dirname "$0")/../.."
mesh="${1:-assets/bunny_100k.mesh}"
venv=target/peers-venv
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q numpy==2.4.6 scipy==1.17.1 meshio==5.3.5 scikit-fem==12.0.2 pbatoolkit==0.0.11 scikit-sparse==0.4.16
fi
mkdir -p target/peers
cargo run --release -q -- bench --only peers --json target/peers/cleave.json > target/peers/cleave.txt
"$venv/bin/python" benches/peers/peers.py "$mesh" target/peers/cleave.json | tee target/peers/table.md
