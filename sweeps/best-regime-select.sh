#!/usr/bin/env bash
# Which configuration of each solver lcpbench's best regime runs: chosen on a held-apart
# configuration, never on the online campaign itself.
#
# The held-apart configuration is the paper authors' scene (paper-lattice, BIM p = 8 at
# eps_gmres 1e-8) at 3x3x3 with another random start than the campaign's (seed=1; the
# campaign's stores use seed 0), in lcpbench's default regime (Krylov recycling and
# quasi-Newton memory across steps on). Every candidate below simulates STEPS steps of it in
# one process, the candidates taking their steps in turn, so that all see the same machine
# load.
#
# The rule, per solver family (BB-PGD, Mono-PQN, Bi-PQN): the candidate with the smallest
# total collision-resolution seconds summed over the steps every candidate solved with at
# least one product (the warm-up step and steps without contacts left out), every one of its
# solves verified (ties: the smaller total step seconds). `lcpbench paper reports/paper`
# applies the rule to this store (it must be the folder named `select`) and prints every
# candidate's sums, the chosen configurations and the sweeps/online-paper.sh command that
# runs them.
#
#   bash sweeps/best-regime-select.sh [OUT] [STEPS]    # default reports/paper/select, 60 steps
#
# Resumable like every simulation: rerunning the same command continues from the last
# finished step.
set -euo pipefail
OUT=${1:-reports/paper/select}
STEPS=${2:-60}
LOWS="p4,p4e6,p8f6e3"
args=()
for s in bb-pgd \
         mono-pqn "mono-pqn:products=iterate" "mono-pqn:products=iterate,relax=0.1" \
         "bi-pqn:low=p4" "bi-pqn:low=p4e6" "bi-pqn:low=p8f6e3" \
         "bi-pqn:low=p4e6,products=iterate,relax=0.1" \
         "bi-pqn:low=p8f6e3,products=iterate,relax=0.1"; do
    args+=(--solver "$s")
done
lcpbench simulate --regime default \
    --scene "paper-lattice:m=3,seed=1,model=bim,p=8,eps_gmres=1e-8,low=[${LOWS}]" \
    "${args[@]}" --steps "${STEPS}" --out "${OUT}"
