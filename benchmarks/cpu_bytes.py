"""Which XLA:CPU settings change a computation's last bits on this host: a table of short digests,
one row per XLA_FLAGS setting, each in a fresh process (XLA reads XLA_FLAGS once).

Run it on two hosts and compare the default rows: equal digests mean the hosts' kernels round
alike for these ops; different ones mean the same run can differ between them in its last bits,
which long training amplifies (Ingolstadt QMIX seed 0 gave t_CAV
5.0097 on one 2-core host and 4.9711 on another). A run records its host in exp_config.json's
`machine`.

    python benchmarks/cpu_bytes.py

Columns: the XLA_FLAGS setting, then sha256 prefixes of a jitted 512x4096x512 product, a tanh
layer of a small MLP, and a row sum, on `jax.random.normal` inputs drawn in the same process.
Recorded on a 2-core host (Intel Xeon family 6 model 207, AVX-512 FP16/BF16, AMX, under KVM):
the default, AVX512 and AVX2 rows equal (e54024fdb8 1e6034d39c 98742fd94c); AVX and SSE4_2 (no
FMA) other bytes for all three; one core and the kernel-library flags the default's bytes.
"""

from __future__ import annotations

import os
import subprocess
import sys

SETTINGS = ["", "--xla_cpu_max_isa=AVX512", "--xla_cpu_max_isa=AVX2", "--xla_cpu_max_isa=AVX",
            "--xla_cpu_max_isa=SSE4_2", "--xla_cpu_multi_thread_eigen=false", "--xla_cpu_use_xnnpack=false",
            "--xla_cpu_use_onednn=true", "--xla_cpu_prefer_vector_width=128"]


def digests() -> str:
    """The three digests of this process's XLA:CPU, space-separated."""
    import hashlib

    import jax
    import jax.numpy as jnp
    import numpy as np

    a = jax.random.normal(jax.random.PRNGKey(0), (512, 4096))
    b = jax.random.normal(jax.random.PRNGKey(1), (4096, 512))
    x = jax.random.normal(jax.random.PRNGKey(2), (64, 256))
    w = jax.random.normal(jax.random.PRNGKey(3), (256, 256)) * 0.05
    outs = (jax.jit(jnp.matmul)(a, b), jax.jit(lambda x, w: jnp.tanh(x @ w).sum(0) + jnp.exp(x).mean())(x, w),
            jax.jit(lambda a: jnp.sum(a, axis=1))(a))
    return " ".join(hashlib.sha256(np.asarray(o).tobytes()).hexdigest()[:10] for o in outs)


def main() -> None:
    if sys.argv[1:] == ["--one"]:
        print(digests())
        return
    import jax

    print(f"{'XLA_FLAGS':40s} {'product':10s} {'mlp':10s} {'row sum':10s}   (jax {jax.__version__})")
    for flags in SETTINGS:
        env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
        done = subprocess.run([sys.executable, __file__, "--one"], env=env, capture_output=True, text=True)
        row = done.stdout.strip() if done.returncode == 0 else f"failed: {done.stderr.strip()[-60:]}"
        print(f"{flags or '(default)':40s} {row}")


if __name__ == "__main__":
    main()
