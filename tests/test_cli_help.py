"""`urb-jax --help` and every `urb-jax CMD --help` answer without importing JAX, flax or pandas.

Building the parser must stay argparse-level (urb_jax/commands/cli.py): the choices come from
urb_jax.core.choices and each command's handler imports what it runs. Each check runs in a fresh
interpreter, since this test process may have imported JAX already. No timings are asserted here.
"""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("jax", "flax", "pandas", "pyarrow", "optax", "libsumo")

# Runs in a child: every command path of the parser (nested ones such as `networks list`
# included) with --help, each one's exit code and output, then which of argv's modules were imported.
_PROBE = """
import argparse, contextlib, io, json, sys
from urb_jax.commands.cli import build_parser, main

def paths(parser, prefix=()):
    yield prefix
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from paths(sub, (*prefix, name))

out = []
for path in paths(build_parser()):
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        try:
            code = main([*path, "--help"])
        except SystemExit as exc:
            code = exc.code
    out.append({"path": path, "code": code, "stdout": buf.getvalue()})
print(json.dumps({"runs": out, "imported": [m for m in sys.argv[1:] if m in sys.modules]}))
"""


def _child(code: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120)


def test_help_of_every_command_imports_no_jax() -> None:
    proc = _child(_PROBE, *HEAVY)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    paths = [tuple(r["path"]) for r in result["runs"]]
    assert () in paths and ("train",) in paths and ("networks", "list") in paths
    for run in result["runs"]:
        cmd = " ".join(["urb-jax", *run["path"]])
        assert run["code"] == 0, (cmd, run)
        assert run["stdout"].startswith(f"usage: {cmd}"), (cmd, run["stdout"][:200])
    assert result["imported"] == [], f"--help imported {result['imported']}"


def test_import_of_the_cli_and_package_imports_no_jax() -> None:
    code = ("import sys, os; import urb_jax, urb_jax.commands.cli; "
            f"print([m for m in {HEAVY!r} if m in sys.modules], 'xla_gpu_deterministic_ops=true' "
            "in os.environ.get('XLA_FLAGS', ''))")
    proc = _child(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["[]", "True"]  # the deterministic-GPU flag is set before any JAX


def test_bad_argument_exits_2_with_argparse_message() -> None:
    for argv in (["--no-such-flag"], ["train", "--alg", "no_such_alg"], ["no-such-command"]):
        proc = subprocess.run([sys.executable, "-m", "urb_jax.commands.cli", *argv], capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 2, (argv, proc.stderr)
        assert "usage: urb-jax" in proc.stderr and "error:" in proc.stderr, (argv, proc.stderr)


def test_light_choices_are_the_implementations_names() -> None:
    """The parser's lists (urb_jax.core.choices) are the ones the heavy modules run."""
    from urb_jax.algorithms.baselines import BASELINES
    from urb_jax.algorithms.registry import _LEARNERS, ALGORITHMS
    from urb_jax.core import choices

    assert list(ALGORITHMS) == list(choices.ALGORITHM_URB_NAMES) == list(_LEARNERS)
    assert tuple(BASELINES) == choices.BASELINE_MODELS
