"""A refactor's proof that it changed nothing: run the reference commands and print each result
file's sha256, one table row a file. Run it on the commit before the change and on the change
(each from its own checkout and virtualenv), then compare the two tables (`diff`).

    python benchmarks/refactor_digests.py OUT_DIR [--networks-dir ../shared/networks] [--quick]

The commands: IQL* St. Arnoult 6,000 days (skipped without --networks-dir), IPPO and QMIX 400 days,
the README's default run, IQL `--mode sumo` 40 days and the AON baseline on urb_grid, and a
PettingZoo Parallel episode (examples/pettingzoo_parallel.py, its printed lines). `--quick` leaves
out the 6,000-day run. The runs are deterministic on one kind of machine, so equal digests mean
equal behaviour.
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
from pathlib import Path

RESULT_FILES = ("records.parquet", "metrics/BenchmarkMetrics.csv", "metrics/VectorMetrics.csv")


def _commands(networks_dir: str | None, quick: bool) -> list[tuple[str, list[str]]]:
    runs = [
        ("ippo_400", ["train", "--alg", "ippo", "--train-days", "400"]),
        ("qmix_400", ["train", "--alg", "qmix", "--train-days", "400"]),
        ("readme_default", ["train"]),
        ("iql_sumo_40", ["train", "--alg", "iql", "--mode", "sumo", "--train-days", "40"]),
        ("baseline_aon", ["baseline", "--model", "aon"]),
    ]
    if networks_dir and not quick:
        runs.insert(0, ("iql_star_saint_arnoult_6000",
                        ["train", "--alg", "iql_star", "--net", "saint_arnoult", "--networks-dir",
                         networks_dir, "--train-days", "6000"]))
    return runs


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for the runs (created; must not hold them yet)")
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--quick", action="store_true", help="leave out the 6,000-day St. Arnoult run")
    args = ap.parse_args()
    cli = str(Path(sys.executable).with_name("urb-jax"))
    rows: list[tuple[str, str, str]] = []
    for exp_id, cmd in _commands(args.networks_dir, args.quick):
        subprocess.run([cli, *cmd, "--id", exp_id, "--results-dir", str(args.out), "--no-progress"],
                       check=True, stdout=subprocess.DEVNULL)
        for name in RESULT_FILES:
            f = args.out / exp_id / name
            rows.append((exp_id, name, _sha(f) if f.is_file() else "missing"))
    example = Path(__file__).resolve().parents[1] / "examples" / "pettingzoo_parallel.py"
    out = subprocess.run([sys.executable, str(example)], check=True, capture_output=True).stdout
    rows.append(("pettingzoo_parallel", "stdout", hashlib.sha256(out).hexdigest()))
    print("| run | file | sha256 |\n|---|---|---|")
    for row in rows:
        print(f"| {' | '.join(row)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
