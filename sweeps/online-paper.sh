#!/usr/bin/env bash
# The method paper's online comparison (its section "Online Comparison": BB-PGD, Mono-PQN and
# Bi-PQN simulating lattices of 3x3x3, 4x4x4, ... spheres, one LCP per time step, high fidelity
# BIM p = 8 at eps_gmres 1e-8), on the paper authors' scene (paper-lattice: 0.3a kept
# separation), in one of two regimes (REGIME, `lcpbench simulate --regime`):
#
# - REGIME=paper: the paper's own: no Krylov recycling, no quasi-Newton memory across time
#   steps, the paper's products, and the paper's online low fidelity BIM p = 4 at eps 1e-8;
# - REGIME=default: lcpbench's defaults: recycling on, quasi-Newton memory across steps, and
#   Bi-PQN's low fidelity the distance-split p8f6e3 (docs/mobility.md).
#
# SCENE=lattice gives the packed 0.1a scene instead.
#
#   bash sweeps/online-paper.sh [OUT] [STEPS]          # default reports/paper/online-$REGIME,
#                                                      # 200 steps, lattices 3x3x3 to 5x5x5
#   LATTICES=6 SEPARATE=1 bash sweeps/online-paper.sh  # the 6x6x6 lattice, one solver per process
#   SOLVERS="bb-pgd mono-pqn:products=iterate" bash sweeps/online-paper.sh   # other solvers
#   SCENE=lattice LOW=p4 bash sweeps/online-paper.sh reports/online-p4 100
#
# Every (lattice, solver) simulation is resumable: rerunning the same command continues each
# from its last finished step, and a larger STEPS extends them. The three solvers of a lattice
# take their steps in turn (one step each, round robin), so that their wall times are measured
# under the same machine load. `lcpbench report OUT` renders the online table and the E-MVP box
# plots per lattice size; `lcpbench paper reports/paper` renders the results page beside the paper.
#
# The simulations of one process hold one operator each (the previous step's is released
# before the next is built; peak memory per simulation: docs/benchmarks.md). SEPARATE=1 runs
# one solver per process instead, CHUNK (default 10) steps at a time, the solvers in turn, so
# each holds only its own operator and all see the same load on average (not step by step);
# resuming works the same.
set -euo pipefail
REGIME=${REGIME:-default}
case "${REGIME}" in
    paper) DEFAULT_LOW=p4 ;;
    default) DEFAULT_LOW=p8f6e3 ;;
    *) echo "online-paper.sh: REGIME=${REGIME} is not a regime; use REGIME=paper or REGIME=default" >&2
       exit 2 ;;
esac
OUT=${1:-reports/paper/online-${REGIME}}
STEPS=${2:-200}
SCENE=${SCENE:-paper-lattice}
LOW=${LOW:-${DEFAULT_LOW}}
CHUNK=${CHUNK:-10}
if [ -n "${SOLVERS:-}" ]; then
    read -r -a SOLVERS <<< "${SOLVERS}"
else
    SOLVERS=(bb-pgd mono-pqn "bi-pqn:low=${LOW}")
fi
for m in ${LATTICES:-3 4 5}; do
    spec="${SCENE}:m=${m},model=bim,p=8,eps_gmres=1e-8,low=[${LOW}]"
    if [ "${SEPARATE:-0}" = 1 ]; then
        # one solver per process, CHUNK steps at a time, in turn: the memory of one
        # simulation (8.9 GB at m = 5 in its first steps), and the same load on average
        k=0
        while [ "$k" -lt "$STEPS" ]; do
            k=$(( k + CHUNK > STEPS ? STEPS : k + CHUNK ))
            for s in "${SOLVERS[@]}"; do
                lcpbench simulate --regime "${REGIME}" --scene "$spec" --solver "$s" --steps "$k" \
                    --out "${OUT}"
            done
        done
    else
        args=()
        for s in "${SOLVERS[@]}"; do args+=(--solver "$s"); done
        lcpbench simulate --regime "${REGIME}" --scene "$spec" "${args[@]}" --steps "${STEPS}" \
            --out "${OUT}"
    fi
done
lcpbench report "${OUT}"
if [ "$(dirname "${OUT}")" = "reports/paper" ]; then lcpbench paper reports/paper; fi
