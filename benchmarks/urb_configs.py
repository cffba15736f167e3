"""Which of URB's config files urb-jax runs: every file of URB's config/{algo_config/*,env_config,
task_config}/ read as urb-jax reads it; prints a markdown table (loaded / refused, and why).

Usage: python benchmarks/urb_configs.py [--by-file] [URB_CONFIG_DIR]   (default ../shared/urb/config)
Rows group the files of one folder that share an outcome (values in reasons shown as `…`);
--by-file prints one row per file.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from urb_jax.core.errors import ConfigError
from urb_jax.runs.urb_configs import load_urb_file

DEFAULT = Path(__file__).resolve().parents[1].parent / "shared" / "urb" / "config"


def status(path: Path) -> tuple[str, str]:
    """('loaded', the aliases applied) or ('refused', the reason without the file name)."""
    try:
        res = load_urb_file(path).resolution
    except ConfigError as exc:
        return "refused", str(exc).replace(f"{path}: ", "")
    renamed = ", ".join(f"{k}→{v}" for k, v in res.aliases.items())
    dropped = ", ".join(f"{k} (ignored)" for k in res.ignored)
    return "loaded", "; ".join(x for x in (renamed, dropped) if x) or "URB's names are ours"


def main(root: Path, by_file: bool = False) -> int:
    files = sorted([*root.glob("algo_config/*/*.json"), *root.glob("env_config/*.json"),
                    *root.glob("task_config/*.json")])
    if not files:
        print(f"no URB config files under {root}", file=sys.stderr)
        return 2
    rows: dict[tuple[str, str, str], list[str]] = {}
    for path in files:
        what, why = status(path)
        folder = str(path.parent.relative_to(root))
        key = (str(path.relative_to(root)) if by_file else folder, what,
               why if by_file else re.sub(r"= ('[^']*'|[\w.-]+)", "= …", why))
        rows.setdefault(key, []).append(path.stem)
    print("| URB config | files | urb-jax | aliases applied / reason |\n|---|---|---|---|")
    for (where, what, why), stems in rows.items():
        print(f"| {where} | {', '.join(stems)} | {what} | {why} |")
    loaded = sum(len(s) for (_, what, _), s in rows.items() if what == "loaded")
    print(f"\n{loaded} loaded, {len(files) - loaded} refused, of {len(files)} files.")
    return 0


if __name__ == "__main__":
    argv = [a for a in sys.argv[1:] if a != "--by-file"]
    sys.exit(main(Path(argv[0]) if argv else DEFAULT, by_file="--by-file" in sys.argv))
