"""XLA's deterministic-GPU flag: set by `import urb_jax`, a user's own value kept (core/determinism.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from urb_jax.core.determinism import FLAG, deterministic_gpu


def test_the_flag_is_added_once_and_other_flags_are_kept():
    env: dict[str, str] = {}
    deterministic_gpu(env)
    assert env["XLA_FLAGS"] == f"{FLAG}=true"
    deterministic_gpu(env)
    assert env["XLA_FLAGS"] == f"{FLAG}=true"
    env = {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}
    deterministic_gpu(env)
    assert env["XLA_FLAGS"] == f"--xla_force_host_platform_device_count=4 {FLAG}=true"


def test_a_users_own_value_wins():
    env = {"XLA_FLAGS": f"{FLAG}=false --xla_dump_to=/tmp/x"}
    deterministic_gpu(env)
    assert env["XLA_FLAGS"] == f"{FLAG}=false --xla_dump_to=/tmp/x"


@pytest.mark.parametrize("given, expected", [(None, f"{FLAG}=true"), (f"{FLAG}=false", f"{FLAG}=false")])
def test_import_urb_jax_sets_it_before_jax_computes(given, expected):
    """In a fresh process: after `import urb_jax`, XLA_FLAGS holds the flag, and JAX (which reads
    XLA_FLAGS when it makes its backend) computes with it accepted on this backend."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if given is not None:
        env["XLA_FLAGS"] = given
    code = ("import os, urb_jax, jax.numpy as jnp; "
            "print(os.environ['XLA_FLAGS']); print(float(jnp.arange(4.0).sum()))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == [expected, "6.0"]
