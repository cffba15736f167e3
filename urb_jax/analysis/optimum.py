"""What could the fleet have done? The system-optimum and selfish-equilibrium references of a run.

URB's learners are judged against AON; nobody knows how far below AON a fleet *could* go on a
network. With a finished run's humans fixed at their first test day's routes, this module searches
the CAVs' joint routes:

* **optimum**: minimise the fleet's objective (mean CAV time for selfish/cooperative fleets, mean
  time of everyone for social/altruistic ones; `objective_weights`) by gradient descent on a
  relaxed choice (softmax over each CAV's routes, temperature annealed toward one-hot) through the
  calibrated, differentiable surrogate, then a discrete local search (best single-CAV moves);
* **equilibrium**: best-response dynamics of selfish CAVs on the same model (a share of the CAVs
  that gain by switching switch, until none gains): the price of anarchy's numerator;

each then **refined with SUMO in the loop**: run the candidate in SUMO, add the day to the
surrogate's data (the per-route residual learns exactly the routes driven), refit, search again
from the candidate, and keep the best SUMO day (the optimum) or the last (the equilibrium). Every
reported number is a SUMO day. Why the SUMO loop: the surrogate's per-agent error (~2.5% on
ingolstadt after correction) is as large as the room the search is looking for.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, cast

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pandas as pd

from urb_jax.city.scenario import Scenario
from urb_jax.core.atomic import write_json
from urb_jax.core.errors import UrbJaxError
from urb_jax.core.ranges import FRACTION, STEPS, Range, above, between, check_ranges
from urb_jax.game.humans import aon_routes
from urb_jax.game.rewards import behaviour_coefficients
from urb_jax.reporting.day_export import recorded_day, run_config, scenario_of_run
from urb_jax.reporting.records import check_scheduled_departures, read_records
from urb_jax.sumo_bridge import ARRIVED, DayExecutor, DayResult, InProcessExecutor
from urb_jax.surrogate import SumoSample, build_static, predict
from urb_jax.surrogate.calibrate import REFIT, FitConfig, Params, fit_with_bias, uncalibrated
from urb_jax.surrogate.model import Static, predict_jit
from urb_jax.training.human_phase import saved_calibration_days
from urb_jax.training.protocol import PHASE_TEST

OBJECTIVES = ("cav", "all", "reward")


@dataclass(frozen=True)
class SearchConfig:
    """Budgets of the search (`urb-jax optimum` flags)."""

    objective: str | None = None  # cav | all | reward; None: from the task's behaviour
    relax_steps: int = 300  # Adam steps of the relaxed search per start
    learning_rate: float = 0.2
    tau_start: float = 1.0  # softmax temperature, annealed geometrically...
    tau_end: float = 0.02  # ...to this
    random_starts: int = 2  # besides AON and the run's own test day
    max_moves: int = 200  # local-search sweeps (each applies >= 1 improving move)
    trust_moves: int = 4  # the trust-region step's CAV moves per SUMO round (at least C / 20)
    screened_moves: int = 6  # single moves per round the surrogate proposes and SUMO judges
    sumo_rounds: int = 8  # SUMO-in-the-loop rounds per reference
    refit_steps: int = 150
    bias_prior: float = 2.0  # route-residual shrinkage (hybrid config route_bias_prior_days)
    switch_share: float = 0.3  # best-response dynamics: share of the gaining CAVs that switch
    seed: int = 0

    RANGES: ClassVar[dict[str, Range]] = {
        "relax_steps": between(1, STEPS), "learning_rate": above(0, 10), "tau_start": above(0, 1e3),
        "tau_end": above(0, 1e3), "random_starts": between(0, 1_000), "max_moves": between(0, STEPS),
        "trust_moves": between(1, 1_000_000), "screened_moves": between(0, 1_000_000),
        "sumo_rounds": between(0, 10_000, "each round runs SUMO days"), "refit_steps": between(0, STEPS),
        "bias_prior": between(0, 1e6), "switch_share": FRACTION, "seed": between(0, 2**31 - 1),
    }

    def __post_init__(self) -> None:
        check_ranges(self)
        if self.objective is not None and self.objective not in OBJECTIVES:
            raise ValueError(f"objective {self.objective!r}: use one of {OBJECTIVES}")


def objective_weights(coefficients: tuple[float, float, float, float], objective: str | None
                      ) -> tuple[str, np.ndarray]:
    """(name, w) with the objective J = w . (t_CAV, t_HDV, t_all), group means, to minimise.

    Default: the mean of everyone when the fleet is paid for everyone's time (social, altruistic:
    d != 0), else the mean CAV time when it is paid for CAV time only (selfish, cooperative,
    collaborative, collectivist), else (`reward`; malicious, competitive, militant) the fleet's
    own total reward, -(mean over CAVs of R_i) = -(a + b) t_CAV - c t_HDV - d t_all."""
    a, b, c, d = coefficients
    if objective is None:
        objective = "all" if d != 0 else ("cav" if c == 0 else "reward")
    w = {"cav": [1.0, 0.0, 0.0], "all": [0.0, 0.0, 1.0], "reward": [-(a + b), -c, -d]}[objective]
    return objective, np.asarray(w, np.float32)


def group_times(times: np.ndarray, is_cav: np.ndarray) -> np.ndarray:
    """(t_CAV, t_HDV, t_all) of times [..., N] (NaN-free minutes)."""
    cav = times[..., is_cav].mean(-1) if is_cav.any() else np.zeros(times.shape[:-1])
    hdv = times[..., ~is_cav].mean(-1) if (~is_cav).any() else np.zeros(times.shape[:-1])
    return np.stack([cav, hdv, times.mean(-1)], -1)


@dataclass
class Problem:
    """One search: the scenario's surrogate, the fixed humans and the objective."""

    static: Static
    valid: np.ndarray  # [N, K] routes that exist
    fixed: np.ndarray  # [N] the run's day: humans' routes (CAV entries are starting points)
    is_cav: np.ndarray  # [N]
    w: np.ndarray  # [3] objective weights
    aon: np.ndarray  # [N] the humans' routes, CAVs on their minimum free-flow route
    cav_index: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.cav_index = np.flatnonzero(self.is_cav)

    def objective(self, params: Params, days: np.ndarray) -> np.ndarray:
        """J of each joint action [D, N] on the surrogate (batched, chunked)."""
        out = []
        for start in range(0, len(days), 1024):
            t = np.asarray(predict_jit(params, self.static, jnp.asarray(days[start:start + 1024], jnp.int32)))
            out.append(group_times(t, self.is_cav) @ self.w)
        return np.concatenate(out)


def relaxed_search(prob: Problem, params: Params, start: np.ndarray, cfg: SearchConfig) -> np.ndarray:
    """Annealed-softmax gradient descent from `start` [N]; the argmax routes [N]."""
    C, K = len(prob.cav_index), prob.valid.shape[1]
    mask = jnp.asarray(prob.valid[prob.cav_index])  # [C, K]
    base = jnp.asarray(np.eye(K, dtype=np.float32)[prob.fixed])  # [N, K] one-hot humans
    cav = jnp.asarray(prob.cav_index)
    w, is_cav = jnp.asarray(prob.w), jnp.asarray(prob.is_cav)
    taus = jnp.asarray(np.geomspace(cfg.tau_start, cfg.tau_end, cfg.relax_steps), jnp.float32)

    def loss(logits: jax.Array, tau: jax.Array) -> jax.Array:
        p = jax.nn.softmax(jnp.where(mask, logits / tau, -1e9), axis=-1)  # [C, K]
        t = predict(params, prob.static, base.at[cav].set(p))  # [N] expected minutes
        groups = jnp.stack([jnp.where(is_cav, t, 0).sum() / jnp.maximum(is_cav.sum(), 1),
                            jnp.where(~is_cav, t, 0).sum() / jnp.maximum((~is_cav).sum(), 1), t.mean()])
        return groups @ w

    opt = optax.adam(cfg.learning_rate)
    logits0 = jnp.asarray(2.0 * np.eye(K, dtype=np.float32)[start[prob.cav_index]])  # [C, K]

    @jax.jit
    def run(logits: jax.Array) -> jax.Array:
        def step(carry, tau):
            x, s = carry
            g = jax.grad(loss)(x, tau)
            upd, s = opt.update(g, s, x)
            return (optax.apply_updates(x, upd), s), None

        (x, _), _ = jax.lax.scan(step, (logits, opt.init(logits)), taus)
        return x

    out = start.copy()
    out[prob.cav_index] = np.asarray(jnp.argmax(jnp.where(mask, run(logits0), -jnp.inf), -1))
    assert out.shape == start.shape and len(prob.cav_index) == C
    return out


def single_moves(prob: Problem, choices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every joint action one CAV away from `choices`: (days [M, N], (cav agent, route) [M, 2])."""
    who = [(i, k) for i in prob.cav_index for k in np.flatnonzero(prob.valid[i]) if k != choices[i]]
    moves = np.asarray(who, np.int64).reshape(-1, 2)
    days = np.repeat(choices[None], len(moves), 0)
    days[np.arange(len(moves)), moves[:, 0]] = moves[:, 1]
    return days, moves


def local_search(prob: Problem, params: Params, choices: np.ndarray, max_moves: int, together: bool = True
                 ) -> np.ndarray:
    """Best-improvement single-CAV moves on the surrogate until none improves J (or `max_moves`
    sweeps). `together`: each sweep also tries the improving moves of distinct CAVs at once
    (largest gains first) and keeps them if that beats the best single move; without it a sweep
    moves one CAV, so at most `max_moves` CAVs change (a trust region)."""
    choices = choices.copy()
    j = prob.objective(params, choices[None])[0]
    for _ in range(max_moves):
        days, moves = single_moves(prob, choices)
        if not len(moves):
            break
        gain = j - prob.objective(params, days)
        if gain.max() <= 1e-6:
            break
        order = np.argsort(-gain)
        order = order[gain[order] > 1e-6]
        if together:
            _, first = np.unique(moves[order, 0], return_index=True)  # each CAV's best move
            best_each = order[np.sort(first)]
            all_moves = choices.copy()
            all_moves[moves[best_each, 0]] = moves[best_each, 1]
            j_all = prob.objective(params, all_moves[None])[0]
            if j - j_all > gain[order[0]]:
                choices, j = all_moves, j_all
                continue
        choices, j = days[order[0]], j - gain[order[0]]
    return choices


def best_response(prob: Problem, params: Params, choices: np.ndarray, cfg: SearchConfig,
                  rng: np.random.Generator, max_iters: int = 100) -> np.ndarray:
    """Selfish CAVs on the surrogate: each iteration a `switch_share` of the CAVs whose own time
    falls by moving alone move to their best route, until none would gain."""
    choices = choices.copy()
    for _ in range(max_iters):
        days, moves = single_moves(prob, choices)
        if not len(moves):
            break
        base = np.asarray(predict_jit(params, prob.static, jnp.asarray(choices[None], jnp.int32)))[0]
        own = np.concatenate([_own_times(prob, params, days[s:s + 1024], moves[s:s + 1024, 0])
                              for s in range(0, len(days), 1024)])
        gain = base[moves[:, 0]] - own
        improving = gain > 1e-4
        if not improving.any():
            break
        best: dict[int, int] = {}
        for m in np.flatnonzero(improving)[np.argsort(-gain[improving])]:
            best.setdefault(int(moves[m, 0]), int(moves[m, 1]))
        agents = np.asarray(sorted(best))
        go = agents[rng.random(len(agents)) < cfg.switch_share]
        if not len(go):
            go = agents[:1]
        choices[go] = [best[int(i)] for i in go]
    return choices


def _own_times(prob: Problem, params: Params, days: np.ndarray, agents: np.ndarray) -> np.ndarray:
    """Each day's mover's own surrogate time [M]."""
    t = np.asarray(predict_jit(params, prob.static, jnp.asarray(days, jnp.int32)))
    return t[np.arange(len(days)), agents]


@dataclass(frozen=True)
class SumoDay:
    """A joint action measured in SUMO, with its objective and group means in both measures."""

    label: str
    choices: np.ndarray
    objective: float
    travel_time: tuple[float, float, float]  # (t_CAV, t_HDV, t_all), URB's current measure
    duration: tuple[float, float, float]  # the same in SUMO trip duration, minutes


class Refiner:
    """SUMO in the loop: measure candidates, learn from them, refit the surrogate."""

    def __init__(self, scn: Scenario, prob: Problem, params: Params, data: SumoSample,
                 executor: DayExecutor, env_seed: int, cfg: SearchConfig) -> None:
        self.scn, self.prob, self.params, self.data = scn, prob, params, data
        self.executor, self.env_seed, self.cfg = executor, env_seed, cfg
        self.measured: dict[bytes, SumoDay] = {}

    def measure(self, label: str, choices: np.ndarray) -> SumoDay:
        return self.measure_all(label, [choices])[0]

    def measure_all(self, label: str, days: list[np.ndarray]) -> list[SumoDay]:
        """SUMO days of joint actions [N] (one executor batch; a day measured before is read back)."""
        keys = [np.asarray(c, np.int32).tobytes() for c in days]
        new = list({k: c for k, c in zip(keys, days, strict=True) if k not in self.measured}.items())
        if new:
            batch = np.stack([c for _, c in new])
            results = self.executor.run_days(self.scn, batch, [self.env_seed] * len(new),
                                             is_cav=self.prob.is_cav)
            for (k, c), res in zip(new, results, strict=True):
                self.measured[k] = self._day(label, c, res)
            self.data = self.data + SumoSample.from_days(batch, results)
        return [self.measured[k] for k in keys]

    def _day(self, label: str, choices: np.ndarray, res: DayResult) -> SumoDay:
        tt = group_times(np.asarray(res.travel_time, np.float64), self.prob.is_cav)
        dur = group_times(np.nan_to_num(np.asarray(res.duration, np.float64) / 60.0), self.prob.is_cav)
        return SumoDay(label, np.asarray(choices).copy(), float(tt @ self.prob.w),  # group_times: 3 each
                       cast("tuple[float, float, float]", tuple(map(float, tt))),
                       cast("tuple[float, float, float]", tuple(map(float, dur))))

    def refit(self) -> None:
        """The smooth model on a fixed-size draw of the days (one compile), then the residual on all."""
        rng = np.random.default_rng([self.cfg.seed, len(self.data)])
        size = 64
        newest = np.arange(max(len(self.data) - size // 2, 0), len(self.data))
        rest = rng.choice(len(self.data), size=size - len(newest), replace=True)
        pick = np.concatenate([newest, rest])
        sub = self.data.days(pick)
        fit = dataclasses.replace(REFIT, steps=self.cfg.refit_steps)
        self.params = fit_with_bias(self.params, self.prob.static, sub, fit, self.data, self.cfg.bias_prior)

    def loop(self, label: str, search: Callable[[Params, np.ndarray], list[tuple[str, np.ndarray]]],
             start: np.ndarray,
             keep_best: bool, log: Callable[[str], None]) -> tuple[SumoDay, list[SumoDay]]:
        """`sumo_rounds` rounds of search -> its candidates' SUMO days -> refit; returns the best
        SUMO day (`keep_best`, searching on from it) or the last, and every day measured."""
        history: list[SumoDay] = []
        current = start
        for r in range(self.cfg.sumo_rounds):
            cands = search(self.params, current)
            days = [self.measure(f"{label}_round{r + 1}_{kind}", c) for kind, c in cands]
            if keep_best and self.cfg.screened_moves:  # SUMO judges the model's best single moves
                days += self.screened(f"{label}_round{r + 1}_screened",
                                      min(history + days, key=lambda d: d.objective))
            history += days
            log(f"{label} round {r + 1}/{self.cfg.sumo_rounds}: {len(days)} SUMO days, best SUMO J "
                f"{min(history, key=lambda d: d.objective).objective:.4f}")
            self.refit()
            current = (min(history, key=lambda d: d.objective) if keep_best else days[-1]).choices
        return (min(history, key=lambda d: d.objective) if keep_best else history[-1]), history


    def screened(self, label: str, best: SumoDay) -> list[SumoDay]:
        """The surrogate's `screened_moves` most promising single-CAV moves from the best SUMO day
        that SUMO has not run yet, each run in SUMO, then all of those SUMO found improving, together."""
        days, moves = single_moves(self.prob, best.choices)
        fresh = np.asarray([np.asarray(d, np.int32).tobytes() not in self.measured for d in days], bool)
        days, moves = days[fresh], moves[fresh]
        if not len(moves):
            return []
        top = np.argsort(self.prob.objective(self.params, days))[:self.cfg.screened_moves]
        measured = self.measure_all(label, list(days[top]))
        better = [m for m, d in zip(top, measured, strict=True) if d.objective < best.objective]
        first: np.ndarray | list[int]
        _, first = np.unique(moves[better, 0], return_index=True) if better else (None, [])
        if len(first) > 1:
            together = best.choices.copy()
            pick = np.asarray(better)[np.sort(first)]
            together[moves[pick, 0]] = moves[pick, 1]
            measured += self.measure_all(label, [together])
        return measured


def optimum_search(prob: Problem, cfg: SearchConfig, rng: np.random.Generator
                   ) -> Callable[[Params, np.ndarray], list[tuple[str, np.ndarray]]]:
    """The optimum's search, two candidates a round: a trust-region step (at most `trust_moves`
    single-CAV moves from the best SUMO day so far, so SUMO measures what the model proposes before
    it proposes more), and a global one (relaxed descent from it, AON and random starts, each
    polished by local search; the best on the surrogate)."""
    def search(params: Params, current: np.ndarray) -> list[tuple[str, np.ndarray]]:
        trust = max(cfg.trust_moves, len(prob.cav_index) // 20)
        step = local_search(prob, params, current, trust, together=False)
        starts = [current, prob.aon]
        for _ in range(cfg.random_starts):
            rand = current.copy()
            n_valid = prob.valid[prob.cav_index].sum(1)
            rand[prob.cav_index] = (rng.random(len(prob.cav_index)) * n_valid).astype(np.int64)
            starts.append(rand)
        cands = [local_search(prob, params, relaxed_search(prob, params, s, cfg), cfg.max_moves)
                 for s in starts]
        j = prob.objective(params, np.stack(cands))
        return [("trust", step), ("global", cands[int(np.argmin(j))])]

    return search


# ---- a finished run's references


def recorded_sample(folder: Path, scn: Scenario) -> SumoSample:
    """Every SUMO day a run recorded (human, training, test days) plus its calibration days, as the
    surrogate's data [D, N] in Scenario order."""
    rec = read_records(folder, columns=["day", "agent", "action", "travel_time", "status", "sumo"])
    rec = rec[rec["sumo"]]
    pos = pd.Series(np.arange(scn.n_agents), index=scn.agent_id)[rec["agent"]].to_numpy()
    days, day_row = np.unique(rec["day"].to_numpy(), return_inverse=True)
    shape = (len(days), scn.n_agents)
    choices, times, arrived = np.zeros(shape, np.int32), np.ones(shape, np.float32), np.zeros(shape, bool)
    choices[day_row, pos] = rec["action"].to_numpy()
    times[day_row, pos] = rec["travel_time"].to_numpy()
    arrived[day_row, pos] = rec["status"].to_numpy() == ARRIVED
    sample, calib = SumoSample(choices, times, arrived), saved_calibration_days(folder)
    return calib + sample if len(calib) else sample


def fit_run_surrogate(static: Static, data: SumoSample, cfg: SearchConfig, steps: int = 600) -> Params:
    """The surrogate fitted from scratch to a run's SUMO days (the newest 64 for the smooth model,
    all of them for the per-route residual)."""
    pick = np.arange(max(len(data) - 64, 0), len(data))
    return fit_with_bias(uncalibrated(static), static, data.days(pick), FitConfig(steps=steps), data,
                         cfg.bias_prior)


def day_json(day: SumoDay) -> dict[str, Any]:
    names = ("t_CAV", "t_HDV", "t_all")
    return {"label": day.label, "objective": round(day.objective, 6),
            **{k: round(v, 6) for k, v in zip(names, day.travel_time, strict=True)},
            **{f"{k}_duration": round(v, 6) for k, v in zip(names, day.duration, strict=True)}}


def run_references(folder: str | Path, networks_dir: str | None = None, cfg: SearchConfig = SearchConfig(),
                   executor: DayExecutor | None = None, log: Callable[[str], None] = print) -> dict[str, Any]:
    """The optimum and equilibrium references of a finished run (humans of its first test day),
    written atomically to RUN/optimum.json; returns what is written."""
    folder = Path(folder)
    t0 = time.perf_counter()
    conf = run_config(folder)
    if float(conf.get("day_participation", 1.0)) < 1.0:
        raise UrbJaxError(f"{folder / 'exp_config.json'}: key 'day_participation' = "
                          f"{conf['day_participation']}: its days vary in who travels, and the optimum "
                          "and equilibrium references are defined for one fixed demand. Fix: ask for the "
                          "references of a run with day_participation 1.")
    check_scheduled_departures(folder, conf, "the optimum and equilibrium references are defined for one "
                                       "fixed demand")
    if conf.get("fleet_agents"):
        raise UrbJaxError(f"{folder / 'exp_config.json'}: the run has competing fleets (key 'fleets'); the "
                          "optimum and equilibrium references are defined for one fleet with one objective. "
                          "Fix: ask for the references of a run without fleets.")
    scn = scenario_of_run(folder, networks_dir)
    rec = read_records(folder, columns=["day", "phase"])
    test_days = rec.loc[rec["phase"] == PHASE_TEST, "day"]
    if test_days.empty:
        raise UrbJaxError(f"{folder}: no test day in the records. Fix: let the run finish (urb-jax train "
                          "--resume) before asking for its references.")
    d0, choices, is_cav, _ = recorded_day(folder, scn, int(test_days.min()))
    if not is_cav.any():
        raise UrbJaxError(f"{folder}: the run has no CAVs, so there is nothing to optimise.")
    coefficients = behaviour_coefficients(conf.get("av_behavior", "selfish"))
    objective, w = objective_weights(coefficients, cfg.objective)
    static = build_static(scn)
    data = recorded_sample(folder, scn)
    log(f"fitting the surrogate to the run's {len(data)} SUMO days")
    params = fit_run_surrogate(static, data, cfg)
    aon = np.where(is_cav, aon_routes(scn.fft, scn.route_valid), choices)
    prob = Problem(static, scn.route_valid, choices.astype(np.int64), is_cav, w, aon.astype(np.int64))
    own = executor is None
    executor = executor or InProcessExecutor()
    try:
        ref = Refiner(scn, prob, params, data, executor, int(conf["env_seed"]), cfg)
        run_day, aon_day = ref.measure("run", prob.fixed), ref.measure("aon", prob.aon)
        start = min((run_day, aon_day), key=lambda d: d.objective).choices
        rng = np.random.default_rng(cfg.seed)
        opt, opt_hist = ref.loop("optimum", optimum_search(prob, cfg, rng), start, True, log)
        opt = min((opt, run_day, aon_day), key=lambda d: d.objective)  # the optimum is the best day seen
        def respond(p: Params, c: np.ndarray) -> list[tuple[str, np.ndarray]]:
            return [("best_response", best_response(prob, p, c, cfg, rng))]

        eq, eq_hist = ref.loop("equilibrium", respond, prob.fixed, False, log)
        # the optimum reference is the best SUMO day any search found (the equilibrium's included)
        opt = min([opt, *eq_hist], key=lambda d: d.objective)
    finally:
        if own:
            executor.close()
    span = aon_day.objective - opt.objective
    out = {
        "run": folder.name, "network": conf.get("network"), "objective": objective,
        "objective_weights": {"t_CAV": float(w[0]), "t_HDV": float(w[1]), "t_all": float(w[2])},
        "humans_from_day": d0, "cavs": int(is_cav.sum()),
        "run_day": day_json(run_day), "aon": day_json(aon_day), "optimum": day_json(opt),
        "equilibrium": day_json(eq),
        "optimality_gap": round(run_day.objective - opt.objective, 6),
        "gap_closed_from_aon": (round((aon_day.objective - run_day.objective) / span, 4)
                                if span > 1e-9 else None),
        "price_of_anarchy": round(eq.objective / opt.objective, 6) if objective != "reward" else None,
        "history": [day_json(d) for d in opt_hist + eq_hist],
        "sumo_days": len(ref.measured), "search_config": dataclasses.asdict(cfg),
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    write_json(folder / "optimum.json", out)
    return out
