#!/usr/bin/env bash
# The method paper's online comparison (its section "Online Comparison": BB-PGD, Mono-PQN and
# Bi-PQN simulating lattices of 3x3x3, 4x4x4, ... spheres, one LCP per time step, high fidelity
# BIM p = 8 at eps_gmres 1e-8). By default on the paper authors' scene (paper-lattice: 0.3a
# kept separation) with Bi-PQN's low fidelity the distance-split p8f6e3 (docs/mobility.md);
# SCENE=lattice LOW=p4 gives the packed 0.1a scene with the paper's own online low (BIM p = 4
# at eps 1e-8).
#
#   bash sweeps/online-paper.sh [OUT] [STEPS]          # default reports/online-paper, 100 steps
#   LATTICES="3 4 5" bash sweeps/online-paper.sh       # add the 5x5x5 lattice
#   SCENE=lattice LOW=p4 bash sweeps/online-paper.sh reports/online-p4 100
#
# Every (lattice, solver) simulation is resumable: rerunning the same command continues each
# from its last finished step, and a larger STEPS extends them. The three solvers of a lattice
# take their steps in turn (one step each, round robin), so that their wall times are measured
# under the same machine load. `lcpbench report OUT` renders the online table and the E-MVP box
# plots per lattice size; the measured table is in docs/benchmarks.md.
set -euo pipefail
OUT=${1:-reports/online-paper}
STEPS=${2:-100}
SCENE=${SCENE:-paper-lattice}
LOW=${LOW:-p8f6e3}
for m in ${LATTICES:-3 4}; do
    lcpbench simulate --scene "${SCENE}:m=${m},model=bim,p=8,eps_gmres=1e-8,low=[${LOW}]" \
        --solver bb-pgd --solver mono-pqn --solver "bi-pqn:low=${LOW}" \
        --steps "${STEPS}" --out "${OUT}"
done
lcpbench report "${OUT}"
