"""The same config and seeds give the same numbers on a GPU too.

XLA:GPU autotunes its matrix kernels when it compiles, and which kernel wins can differ from one
process to the next, so two runs of the same program can differ in the last bits, which training
amplifies. Measured on one H100 (docs/results.md, "GPU"): URB's QMIX config1 on urb_grid, two
seeds, gave seed 1 different records in two processes; with `--xla_gpu_deterministic_ops=true`
two processes on two machines gave the same bytes. XLA reads XLA_FLAGS when it creates its
backend, so the flag goes in before JAX's first computation: `import urb_jax` sets it (the
package's __init__), which every entry point does first; a script that computed with JAX before
importing urb_jax must set XLA_FLAGS itself (docs/api.md). A value the user gave wins; XLA:CPU,
deterministic already, ignores the flag.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

FLAG = "--xla_gpu_deterministic_ops"


def deterministic_gpu(environ: MutableMapping[str, str] = os.environ) -> None:
    """Add `--xla_gpu_deterministic_ops=true` to XLA_FLAGS unless the flag is there already."""
    flags = environ.get("XLA_FLAGS", "")
    if FLAG not in flags:
        environ["XLA_FLAGS"] = f"{flags} {FLAG}=true".strip()
