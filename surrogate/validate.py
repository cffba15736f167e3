"""Surrogate vs SUMO on held-out days: error metrics, better-route agreement, report and plots."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from urb_jax.city.scenario import Scenario
from urb_jax.core.atomic import write_json, write_npz, write_text
from urb_jax.sumo_bridge.types import DayResult
from urb_jax.surrogate.calibrate import FitConfig, SumoSample, calibrate
from urb_jax.surrogate.data import make_choices
from urb_jax.surrogate.model import SurrogateConfig, build_static, init_params, predict_jit
from urb_jax.surrogate.sumo_days import backend_name, sumo_days


@dataclass(frozen=True)
class ValidationConfig:
    train_days: int = 40
    test_days: int = 10
    deviation_agents: int = 30  # agents whose K-1 single-agent deviations are re-simulated
    noise_agents: int = 10  # of those, how many are re-simulated with a second SUMO seed
    seed: int = 42  # SUMO seed (URB: env_seed, same every day)
    workers: int = 2
    day_store: bool = True  # read and keep SUMO days in the shared day store (sumo_bridge.memo)


def _days(vcfg: ValidationConfig, scn: Scenario, choices: np.ndarray, seed: int, workers: int
          ) -> list[DayResult]:
    """SUMO days, through the day store unless `vcfg.day_store` is False."""
    return sumo_days(scn, choices, seed, workers=workers, use_cache=vcfg.day_store)


def error_metrics(pred: np.ndarray, sample: SumoSample) -> dict[str, float]:
    """Mean-travel-time error (per day, relative), per agent-day MAPE and R² over arrived agents."""
    y, m = sample.travel_time, sample.arrived
    day_err = np.array([abs(pred[d][m[d]].mean() - y[d][m[d]].mean()) / y[d][m[d]].mean()
                        for d in range(len(y))])
    res = (pred - y)[m]
    return {
        "mean_tt_error": float(day_err.mean()),
        "mean_tt_error_max": float(day_err.max()),
        "mape": float(np.mean(np.abs(res) / y[m])),
        "r2": float(1 - np.sum(res**2) / np.sum((y[m] - y[m].mean()) ** 2)),
        "bias": float(np.mean(res / y[m])),
        "sumo_mean_tt": float(y[m].mean()),
        "surrogate_mean_tt": float(pred[m].mean()),
        "removed": int((~m).sum()),
    }


def binned_bias(key: np.ndarray, rel: np.ndarray, edges: np.ndarray) -> list[dict[str, float]]:
    out = []
    idx = np.clip(np.digitize(key, edges[1:-1]), 0, len(edges) - 2)
    for b in range(len(edges) - 1):
        sel = idx == b
        if sel.any():
            out.append({"lo": float(edges[b]), "hi": float(edges[b + 1]), "n": int(sel.sum()),
                        "bias": float(rel[sel].mean()), "mape": float(np.abs(rel[sel]).mean())})
    return out


def deviation_choices(base: np.ndarray, agents: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, list]:
    """One joint action per (agent, alternative route): the base day with that agent switched."""
    rows, meta = [], []
    for i in agents:
        for k in range(valid.shape[1]):
            if k != base[i] and valid[i, k]:
                ch = base.copy()
                ch[i] = k
                rows.append(ch)
                meta.append((int(i), int(k)))
    return np.stack(rows), meta


def route_agreement(base_t: np.ndarray, dev_t: np.ndarray, base: np.ndarray, meta: list,
                    k: int) -> dict[str, float]:
    """Pairwise (chosen vs alternative: which is faster) and argmin agreement between two predictors.

    base_t/dev_t: [2, ...] times of (reference, model) for the base day [2, N] and deviations [2, R].
    """
    pair = []
    by_agent: dict[int, np.ndarray] = {}
    for r, (i, kk) in enumerate(meta):
        d_ref = dev_t[0, r] - base_t[0, i]
        d_mod = dev_t[1, r] - base_t[1, i]
        pair.append((np.sign(d_ref), np.sign(d_mod), abs(d_ref)))
        tab = by_agent.setdefault(i, np.full((2, k), np.inf))
        tab[:, kk] = dev_t[:, r]
        tab[:, base[i]] = base_t[:, i]
    p = np.array(pair)
    agree = p[:, 0] == p[:, 1]
    clear = p[:, 2] >= 0.25  # SUMO difference of at least 15 s
    argmin = np.mean([t[0].argmin() == t[1].argmin() for t in by_agent.values()])
    return {
        "pairs": len(p),
        "pair_agreement": float(agree.mean()),
        "pair_agreement_clear": float(agree[clear].mean()) if clear.any() else float("nan"),
        "clear_pairs": int(clear.sum()),
        "argmin_agreement": float(argmin),
    }


def validate(scn: Scenario, out_dir: Path, vcfg: ValidationConfig | None = None,
             config: SurrogateConfig | None = None, fit: FitConfig | None = None) -> dict:
    """Calibrate on generated SUMO days, evaluate on held-out ones, write report.md + plots + JSON."""
    vcfg, config, fit = vcfg or ValidationConfig(), config or SurrogateConfig(), fit or FitConfig()
    t_start = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    static = build_static(scn, config)
    p0 = init_params(static)
    # the days are drawn with the BPR model whichever model is validated: every model meets the same days
    bpr = static if config.model == "bpr" else build_static(scn, replace(config, model="bpr"))
    c_tr, _ = make_choices(scn, bpr, init_params(bpr), vcfg.train_days, seed=1)
    c_te, kinds = make_choices(scn, bpr, init_params(bpr), vcfg.test_days, seed=2)
    t0 = time.perf_counter()
    tr = SumoSample.from_days(c_tr, _days(vcfg, scn, c_tr, vcfg.seed, workers=vcfg.workers))
    te = SumoSample.from_days(c_te, _days(vcfg, scn, c_te, vcfg.seed, workers=vcfg.workers))
    t_sumo = time.perf_counter() - t0
    t0 = time.perf_counter()
    # the smooth model alone (no route residual): what the fidelity targets are stated for
    params = calibrate(scn, tr, config=config, fit=fit, static=static, route_bias_prior_days=None)
    t_fit = time.perf_counter() - t0
    write_npz(out_dir / "params.npz", **{k: np.asarray(v) for k, v in params.items()})

    def predictor(p: dict) -> Callable[[np.ndarray], np.ndarray]:
        return lambda choices: np.asarray(predict_jit(p, static, jnp.asarray(choices)))

    surrogate, uncalibrated = predictor(params), predictor(p0)
    pred, pred0 = surrogate(c_te), uncalibrated(c_te)  # [D, N]
    fft = free_flow_times(scn, c_te)  # [D, N]
    metrics: dict[str, Any] = {"held_out": error_metrics(pred, te), "uncalibrated": error_metrics(pred0, te),
               "train": error_metrics(surrogate(c_tr), tr)}
    dep, ratio, bias = _bias(scn, pred, te, fft)
    metrics.update(bias)
    metrics["by_kind"] = {}
    for kd in sorted(set(kinds)):
        rows = [i for i, x in enumerate(kinds) if x == kd]
        metrics["by_kind"][kd] = error_metrics(pred[rows], te.days(rows))

    agents, dev, dev_meta = _deviations(scn, c_te, kinds, vcfg)
    t0 = time.perf_counter()
    dev_sumo = np.stack([d.travel_time for d in _days(vcfg, scn, dev, vcfg.seed, workers=vcfg.workers)])
    t_dev = time.perf_counter() - t0
    models = {"surrogate": (pred, surrogate(dev)), "free_flow": (fft, free_flow_times(scn, dev)),
              "uncalibrated": (pred0, uncalibrated(dev))}
    metrics["route_agreement"] = {
        name: _pool_agreement(_agreement_items(te, dev_sumo, dev_meta, c_te, *m), scn.k)
        for name, m in models.items()}
    metrics.update(_noise_floor(scn, vcfg, agents[: vcfg.noise_agents], c_te, te, dev, dev_meta, dev_sumo,
                                metrics["route_agreement"]))

    metrics["timing_s"] = {"sumo_days": round(t_sumo, 1), "calibration": round(t_fit, 1),
                           "deviation_days": round(t_dev, 1),
                           "total": round(time.perf_counter() - t_start, 1)}
    metrics["setup"] = {"network": scn.name, "agents": scn.n_agents, "edges": scn.n_edges,
                        "sumo_backend": backend_name(), "validation": asdict(vcfg), "model": asdict(config),
                        "fit": asdict(fit), "test_kinds": kinds, "deviation_days": len(dev)}
    write_json(out_dir / "metrics.json", metrics)
    _plots(out_dir, pred, te, dep, ratio)
    write_text(out_dir / "report.md", _report(metrics))
    return metrics


def _bias(scn: Scenario, pred: np.ndarray, te: SumoSample,
          fft: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """The held-out relative error binned by departure minute and by congestion (SUMO time over
    free-flow time), with the departures [D, N] and the congestion ratios [D, N] the plots use."""
    m = te.arrived
    rel = np.where(m, (pred - te.travel_time) / te.travel_time, np.nan)
    dep = np.broadcast_to(scn.agent_depart, rel.shape)
    ratio = te.travel_time / fft
    return dep, ratio, {
        "bias_by_depart_min": binned_bias(dep[m] / 60, rel[m], np.arange(0, 31 + 5, 5.0)),
        "bias_by_congestion": binned_bias(ratio[m], rel[m],
                                          np.quantile(ratio[m], [0, 0.2, 0.4, 0.6, 0.8, 1.0])),
    }


def _deviations(scn: Scenario, c_te: np.ndarray, kinds: list[str],
                vcfg: ValidationConfig) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, int]]]:
    """Single-agent deviations from the held-out equilibrium-like and perturbed days: the agents
    drawn, the deviation days [R, N] and each row's (held-out day, agent, route)."""
    rng = np.random.default_rng(vcfg.seed)
    base_days = [i for i, kd in enumerate(kinds) if kd in ("equilibrium", "perturbed")] or [0]
    agents = rng.choice(scn.n_agents, size=min(vcfg.deviation_agents, scn.n_agents), replace=False)
    dev_rows, dev_meta = [], []
    for j, chunk in enumerate(np.array_split(agents, len(base_days))):
        if len(chunk) == 0:
            continue
        rows, meta = deviation_choices(c_te[base_days[j]], chunk, scn.route_valid)
        dev_rows.append(rows)
        dev_meta += [(base_days[j], i, k) for i, k in meta]
    return agents, np.concatenate(dev_rows), dev_meta


def free_flow_times(scn: Scenario, choices: np.ndarray) -> np.ndarray:
    """Each agent's free-flow time on its chosen route, per day [D, N]: the baseline predictor."""
    return np.take_along_axis(scn.fft_full, choices.T, axis=1).T


def _agreement_items(te: SumoSample, dev_sumo: np.ndarray, dev_meta: list[tuple[int, int, int]],
                     c_te: np.ndarray, model_base: np.ndarray, model_dev: np.ndarray) -> list[tuple]:
    """Per held-out day: SUMO's and the model's times of the base day and of its deviations, for
    `_pool_agreement`."""
    items = []
    for bd in sorted({b for b, _, _ in dev_meta}):
        sel = [r for r, (b, _, _) in enumerate(dev_meta) if b == bd]
        meta = [(i, k) for b, i, k in dev_meta if b == bd]
        idx = [i for i, _ in meta]
        items.append((np.stack([te.travel_time[bd], model_base[bd]]),
                      np.stack([dev_sumo[sel, idx], model_dev[sel, idx]]), c_te[bd], meta))
    return items


def _noise_floor(scn: Scenario, vcfg: ValidationConfig, noise_agents: np.ndarray, c_te: np.ndarray,
                 te: SumoSample, dev: np.ndarray, dev_meta: list[tuple[int, int, int]], dev_sumo: np.ndarray,
                 agreement: dict) -> dict:
    """The same deviation experiment for a few agents with another SUMO seed: how often SUMO agrees
    with itself (added to `agreement`), and its seed-to-seed per-agent MAPE on the base days."""
    sel = [r for r, (_, i, _) in enumerate(dev_meta) if i in set(noise_agents.tolist())]
    if not sel:
        return {}
    bds = sorted({dev_meta[r][0] for r in sel})
    base2 = {bd: _days(vcfg, scn, c_te[bd:bd + 1], vcfg.seed + 1, workers=1)[0].travel_time for bd in bds}
    dev2 = np.stack([d.travel_time for d in _days(vcfg, scn, dev[sel], vcfg.seed + 1, workers=vcfg.workers)])
    base2_days = np.full(te.travel_time.shape, np.nan)  # [D, N] float64 as SUMO gives, the base days again
    for bd in bds:
        base2_days[bd] = base2[bd]
    items = _agreement_items(te, dev_sumo[sel], [dev_meta[r] for r in sel], c_te, base2_days, dev2)
    agreement["sumo_seed_vs_seed"] = _pool_agreement(items, scn.k)
    return {"seed_to_seed_mape_base": float(np.mean([
        np.mean(np.abs(base2[bd] - te.travel_time[bd]) / te.travel_time[bd]) for bd in bds]))}


def _pool_agreement(items: list, k: int) -> dict[str, float]:
    """Agreement pooled over base days (each item: ref/model times for base and deviations)."""
    stats = [route_agreement(b, d, base, meta, k) for b, d, base, meta in items]
    n = sum(s["pairs"] for s in stats)
    nc = sum(s["clear_pairs"] for s in stats)
    na = sum(len({i for i, _ in it[3]}) for it in items)
    return {
        "pairs": n,
        "pair_agreement": sum(s["pair_agreement"] * s["pairs"] for s in stats) / n,
        "clear_pairs": nc,
        "pair_agreement_clear": (sum(s["pair_agreement_clear"] * s["clear_pairs"] for s in stats
                                     if s["clear_pairs"]) / nc) if nc else float("nan"),
        "argmin_agreement": sum(s["argmin_agreement"] * len({i for i, _ in it[3]})
                                for s, it in zip(stats, items, strict=True)) / na,
    }


def _plots(out_dir: Path, pred: np.ndarray, te: SumoSample, dep: np.ndarray, ratio: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = te.arrived
    y, p = te.travel_time[m], pred[m]
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    ax[0].scatter(y, p, s=3, alpha=0.3)
    hi = float(max(y.max(), p.max()))
    ax[0].plot([0, hi], [0, hi], "k--", lw=1)
    ax[0].set(xlabel="SUMO travel time (min)", ylabel="surrogate (min)", title="agent-days, held out")
    ax[1].scatter(dep[m] / 60, p - y, s=3, alpha=0.3)
    ax[1].axhline(0, color="k", lw=1)
    ax[1].set(xlabel="departure (min)", ylabel="surrogate - SUMO (min)", title="residual by departure")
    ax[2].scatter(ratio[m], (p - y) / y, s=3, alpha=0.3)
    ax[2].axhline(0, color="k", lw=1)
    ax[2].set(xlabel="SUMO time / free-flow time", ylabel="relative error", title="by congestion")
    fig.tight_layout()
    fig.savefig(out_dir / "scatter_residuals.png", dpi=110)
    plt.close(fig)


def _report(mt: dict) -> str:
    s = mt["setup"]
    h, u = mt["held_out"], mt["uncalibrated"]
    lines = [
        f"# Surrogate validation: {s['network']}",
        "",
        f"{s['agents']} agents, {s['edges']} edges; SUMO backend `{s['sumo_backend']}`; "
        f"{s['validation']['train_days']} calibration days, {s['validation']['test_days']} held-out days "
        f"({', '.join(s['test_kinds'])}); {s['deviation_days']} single-agent deviation days.",
        "",
        "| metric (held-out days) | calibrated | uncalibrated | target |",
        "|---|---|---|---|",
        f"| mean travel time error | {h['mean_tt_error']:.2%} (max {h['mean_tt_error_max']:.2%}) | "
        f"{u['mean_tt_error']:.2%} | <= 3% |",
        f"| per agent-day MAPE | {h['mape']:.2%} | {u['mape']:.2%} | <= 10% |",
        f"| R² (agent-days) | {h['r2']:.3f} | {u['r2']:.3f} | |",
        f"| bias (mean relative error) | {h['bias']:+.2%} | {u['bias']:+.2%} | |",
        f"| mean travel time SUMO / surrogate (min) | {h['sumo_mean_tt']:.3f} / "
        f"{h['surrogate_mean_tt']:.3f} | | |",
        "",
        "## Better-route agreement (single-agent deviations re-simulated in SUMO)",
        "",
        "| predictor | pairs agree | pairs with |ΔSUMO| ≥ 15 s agree | fastest route agrees |",
        "|---|---|---|---|",
    ]
    for name, a in mt["route_agreement"].items():
        lines.append(f"| {name} | {a['pair_agreement']:.1%} ({a['pairs']}) | "
                     f"{a['pair_agreement_clear']:.1%} ({a['clear_pairs']}) | {a['argmin_agreement']:.1%} |")
    if "seed_to_seed_mape_base" in mt:
        lines += ["", f"SUMO seed-to-seed per-agent MAPE on the same joint action: "
                      f"{mt['seed_to_seed_mape_base']:.2%} (noise floor of the per-agent error)."]
    lines += ["", "## Bias by departure time", "", "| departure (min) | n | bias | MAPE |",
              "|---|---|---|---|"]
    lines += [f"| {b['lo']:.0f}–{b['hi']:.0f} | {b['n']} | {b['bias']:+.2%} | {b['mape']:.2%} |"
              for b in mt["bias_by_depart_min"]]
    lines += ["", "## Bias by congestion (SUMO time / free-flow time, quintiles)", "",
              "| ratio | n | bias | MAPE |", "|---|---|---|---|"]
    lines += [f"| {b['lo']:.2f}–{b['hi']:.2f} | {b['n']} | {b['bias']:+.2%} | {b['mape']:.2%} |"
              for b in mt["bias_by_congestion"]]
    lines += ["", "## By kind of joint action", "", "| kind | mean tt error | MAPE | R² |",
              "|---|---|---|---|"]
    lines += [f"| {k} | {v['mean_tt_error']:.2%} | {v['mape']:.2%} | {v['r2']:.3f} |"
              for k, v in mt["by_kind"].items()]
    t = mt["timing_s"]
    lines += ["", f"Timing: SUMO days {t['sumo_days']} s, calibration {t['calibration']} s, "
                  f"deviations {t['deviation_days']} s, total {t['total']} s.", "",
              "![scatter and residuals](scatter_residuals.png)", ""]
    return "\n".join(lines)
