"""What each surrogate term buys: held-out error with one term removed at a time (same SUMO days).

    python benchmarks/surrogate_ablation.py --networks-dir ../shared/networks --nets saint_arnoult

Uses the calibration/held-out SUMO days of `urb-jax validate-surrogate` (cached; run here if absent).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import load_scenario
from urb_jax.surrogate.calibrate import FitConfig, SumoSample, fit_params
from urb_jax.surrogate.data import make_choices
from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict_jit
from urb_jax.surrogate.sumo_days import sumo_days
from urb_jax.surrogate.validate import error_metrics

EDGE = ("log_speed_e", "log_a_e", "log_junc_e")
OFF = -30.0
VARIANTS: dict[str, tuple[dict, dict, tuple[str, ...]]] = {
    # name: (SurrogateConfig overrides, parameter overrides, frozen parameters)
    "full model": ({}, {}, ()),
    "no time dependence (one bin)": ({"bin_s": 1e5}, {}, ()),
    "hard bins (no interpolation)": ({"interpolate": False}, {}, ()),
    "bins of 150 s": ({"bin_s": 150.0}, {}, ()),
    "bins of 600 s": ({"bin_s": 600.0}, {}, ()),
    "entry times at free flow (gamma=1)": ({"entry_scale": 1.0}, {}, ()),
    "no BPR term": ({}, {"log_a_c": OFF}, ("log_a_c", "log_a_e")),
    "no junction delay": ({}, {"log_junc_j": OFF}, ("log_junc_j", "log_junc_e")),
    "no insertion term": ({}, {"log_ins": OFF}, ("log_ins",)),
    "no per-edge deviations": ({}, {}, EDGE),
    "no per-agent speed factor": ({}, {}, ("log_agent",)),
    "speed factor only (t0*s + c0)": ({}, {"log_a_c": OFF, "log_junc_j": OFF, "log_ins": OFF},
                                      ("log_a_c", "log_junc_j", "log_ins", "log_agent", *EDGE)),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks-dir", default=None)
    ap.add_argument("--nets", default="saint_arnoult,provins,ingolstadt_custom")
    ap.add_argument("--train-days", type=int, default=40)
    ap.add_argument("--test-days", type=int, default=10)
    ap.add_argument("--variants", default="", help="comma-separated subset of variant names")
    args = ap.parse_args()
    names = [v for v in args.variants.split(",") if v] or list(VARIANTS)
    for net in args.nets.split(","):
        scn = load_scenario(net, networks_dir=args.networks_dir)
        st0 = build_static(scn)
        p_init = init_params(st0)
        c_tr, _ = make_choices(scn, st0, p_init, args.train_days, seed=1)
        c_te, _ = make_choices(scn, st0, p_init, args.test_days, seed=2)
        tr = SumoSample.from_days(c_tr, sumo_days(scn, c_tr, 42))
        te = SumoSample.from_days(c_te, sumo_days(scn, c_te, 42))
        print(f"\n### {net}\n\n| variant | mean tt error | MAPE | R² | bias | fit s |")
        print("|---|---|---|---|---|---|")
        for name in names:
            cfg_over, p_over, frozen = VARIANTS[name]
            static = build_static(scn, replace(SurrogateConfig(), **cfg_over))
            params = init_params(static)
            params.update({k: jnp.full_like(params[k], v) for k, v in p_over.items()})
            t0 = time.perf_counter()
            fitted = fit_params(params, static, tr, FitConfig(frozen=frozen))
            dt = time.perf_counter() - t0
            m = error_metrics(np.asarray(predict_jit(fitted, static, jnp.asarray(c_te))), te)
            print(f"| {name} | {m['mean_tt_error']:.2%} | {m['mape']:.2%} | {m['r2']:.3f} | "
                  f"{m['bias']:+.2%} | {dt:.1f} |", flush=True)
        m0 = error_metrics(np.asarray(predict_jit(p_init, st0, jnp.asarray(c_te))), te)
        print(f"| uncalibrated full model | {m0['mean_tt_error']:.2%} | {m0['mape']:.2%} | {m0['r2']:.3f} | "
              f"{m0['bias']:+.2%} | 0 |")


if __name__ == "__main__":
    main()
