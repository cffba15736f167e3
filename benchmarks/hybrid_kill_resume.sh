#!/bin/bash
# kill -9 demo: uninterrupted reference vs killed-in-round-3 + --resume; same seeds.
# SEEDS=0,1 trains a vmapped seed group (checkpoints in the first seed's folder; resumed by the
# last seed's id, which names the whole group).
OUT=${1:-/tmp/hyb_kill}; mkdir -p $OUT; cd $OUT
B=${URB_JAX:-urb-jax}
ARGS="--task-conf test --train-days 3000 --results-dir $OUT/results --overwrite ${SEEDS:+--seeds $SEEDS}"
if [ -n "$SEEDS" ]; then SUF=(${SEEDS//,/ }); SUF=("${SUF[@]/#/_s}"); else SUF=(""); fi
timeout 900 $B train $ARGS --id ref > ref.log 2>&1
timeout 900 $B train $ARGS --id killed > killed.log 2>&1 &
PID=$!
while [ ! -f results/killed${SUF[0]}/checkpoints/round_00002/meta.json ]; do sleep 0.2; done
sleep 2.5
echo "phase at kill: $(tr '\r' '\n' < killed.log | grep -v '^\s*$' | tail -1 | cut -c1-40)" > kill.txt
pkill -9 -P $PID; kill -9 $PID   # the timeout wrapper's child (urb-jax) and the wrapper
sleep 1
ls results/killed${SUF[0]}/checkpoints >> kill.txt
timeout 900 $B train --resume killed${SUF[-1]} --results-dir $OUT/results > resume.log 2>&1
for s in "${SUF[@]}"; do
  diff results/ref$s/metrics/BenchmarkMetrics.csv results/killed$s/metrics/BenchmarkMetrics.csv \
    && echo "METRICS IDENTICAL${s:+ (seed ${s#_s})}" >> kill.txt
done
