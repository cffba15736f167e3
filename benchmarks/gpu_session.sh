#!/bin/bash
# The GPU throughput checks, in one call (the device machine has JAX/flax/optax but no
# SUMO or pettingzoo; these benchmarks need neither). NETS: a folder with the URB networks named below
# (copy them into a git-ignored folder of the checkout and carry it). Writes its tables under $OUT.
#   NETS=.gpu_nets OUT=/tmp/out bash benchmarks/gpu_session.sh
set -o pipefail
export PYTHONPATH=$PWD PYTHONUNBUFFERED=1
NETS=${NETS:?folder of URB networks}; OUT=${OUT:?output folder}; PY=${PY:-python3}
$PY -c "import jax, flax, optax; print('jax', jax.__version__, 'flax', flax.__version__, 'optax', optax.__version__, jax.devices())"
nvidia-smi --query-gpu=name,memory.total,clocks.sm,clocks.max.sm --format=csv 2>/dev/null
# The catalogue's two seed-group QMIX runs: Ingolstadt (3 seeds), St. Arnoult Scenario 2 (5 seeds).
$PY benchmarks/seed_axis.py --alg qmix --net ingolstadt_custom --envs 16 --seeds 3 --networks-dir "$NETS" \
    2>&1 | tee "$OUT/seed_axis_ingolstadt_qmix.txt"
$PY benchmarks/seed_axis.py --alg qmix --net saint_arnoult --ratio 1.0 --envs 16 --seeds 5 --networks-dir "$NETS" \
    2>&1 | tee "$OUT/seed_axis_saint_arnoult_qmix_full.txt"
# Training days/s of every learner, URB's config1, B=64 (docs/results.md, "GPU").
$PY benchmarks/train_speed.py --networks-dir "$NETS" --networks ingolstadt_custom saint_arnoult \
    --algs qmix iql ippo mappo vdn iql_star ippo_star --envs 64 --config config1 --standin --min-days 2000 \
    2>&1 | tee "$OUT/train_speed_config1_b64.txt"
