#!/usr/bin/env bash
# The cantilever study of docs/study.md: control only in the first model, strips of 4-32 photos,
# every method, 30 trials. Prints growth.csv (error at the strip end = a n^b per method) and
# precision.csv (predicted against measured). About 2-3 minutes on 2 cores.
set -euo pipefail
out=${1:-out/study_cantilever}
striptri compare --out "$out" --methods seq1-forward seq1-backward seq2-forward seq2-backward conditions bundle \
    --photos 4 8 16 32 --layouts cantilever --trials 30 --seed 2
column -s, -t < "$out/growth.csv"
echo
column -s, -t < "$out/precision.csv"
