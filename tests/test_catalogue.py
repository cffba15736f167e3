"""The paper's experiment catalogue (configs/suites/*.json): every entry loads, every run's configs
resolve to what the paper states, and every network it names is a real URB network."""

from __future__ import annotations

import pytest
from support.catalogue import CATALOGUE, SUITES

from urb_jax.algorithms.registry import load_algo_config
from urb_jax.core.configio import find_config
from urb_jax.game.config import load_env_config, load_task_config
from urb_jax.runs.suite import load_suite
from urb_jax.training.hybrid.plan import load_hybrid_config


def _trains(name: str):
    return [r for r in load_suite(find_config("suites", name)).runs if r.kind == "train"]


@pytest.mark.parametrize("name", CATALOGUE)
def test_every_catalogue_entry_loads_and_its_configs_resolve(name):
    spec = load_suite(find_config("suites", name))
    assert spec.title and "paper" in spec.preamble.lower()
    for run in spec.runs:
        args = run.kwargs
        task, _ = load_task_config(args.get("task_conf", "config1"))
        load_env_config(args.get("env_conf", "config1"))
        if run.kind == "train":
            load_algo_config(args["alg"], args.get("alg_conf", "config1"))
            load_hybrid_config(args.get("hybrid_conf", "default"))
            assert args["seeds"] and args["train_days"] >= 1
        assert 0 < task.ratio_machines <= 1


def test_the_catalogue_states_the_papers_protocol():
    s1 = _trains("scenario1")
    assert {(r.kwargs["net"], r.kwargs["alg"]) for r in s1} == {
        (n, a) for n in ("saint_arnoult", "provins", "ingolstadt_custom")
        for a in ("iql", "ippo", "mappo", "qmix", "vdn")}
    for r in s1:  # selfish independent learners, cooperative team learners; 6,000 days, 5 seeds
        task, _ = load_task_config(r.kwargs["task_conf"])
        assert task.av_behavior == ("selfish" if r.kwargs["alg"] in ("iql", "ippo") else "cooperative")
        assert (task.ratio_machines, task.human_learning_episodes, task.test_eps) == (0.4, 200, 100)
        # but 3 seeds, one at a time, for Ingolstadt's QMIX config1 (about 2.5 h a seed on 2 CPU
        # cores), where time forces it, and the entry's preamble says so
        fewer = r.exp_id == "s1_ingolstadt_custom_qmix"
        assert r.kwargs["train_days"] == 6000
        assert r.kwargs["seeds"] == ([0, 1, 2] if fewer else [0, 1, 2, 3, 4])
    assert "3 for Ingolstadt's QMIX" in load_suite(find_config("suites", "scenario1")).preamble
    for r in _trains("scenario2"):  # full autonomy
        assert load_task_config(r.kwargs["task_conf"])[0].ratio_machines == 1.0
        assert r.kwargs["net"] == "saint_arnoult"
    assert {r.kwargs["train_days"] for r in _trains("adjusted_iql_ippo")} == {2000}
    assert {r.kwargs["alg"] for r in _trains("adjusted_iql_ippo")} == {"iql_star", "ippo_star"}
    demos = {"demo_nangis_selfish_adapt": ("nangis", "ippo", "selfish", True),
             "demo_nemours_malicious": ("nemours", "qmix", "malicious", False),
             "demo_gretz_altruistic_adapt": ("gretz_armainvilliers", "vdn", "altruistic", True)}
    for name, (net, alg, behaviour, adapt) in demos.items():
        # the paper's deterministic humans (sec:humans) first, at exactly 6,000 days; URB's task file's
        # stochastic humans kept as a labelled extra
        paper_run, extra = _trains(name)
        tasks = [load_task_config(r.kwargs["task_conf"])[0] for r in (paper_run, extra)]
        for run, task in zip((paper_run, extra), tasks, strict=True):
            assert (run.kwargs["net"], run.kwargs["alg"], task.av_behavior, task.should_humans_adapt) == (
                net, alg, behaviour, adapt)
        assert [t.human_deterministic for t in tasks] == [True, False]
        assert paper_run.kwargs["task_conf"] == f"{extra.kwargs['task_conf']}_deterministic"
        over = paper_run.kwargs["overrides"]  # 12 rounds of 480 surrogate + 20 SUMO days
        assert {"hybrid.num_envs=24", "hybrid.surrogate_days_per_round=480",
                "hybrid.sumo_days_per_round=20"} <= set(over)
    for name, scale in {"sensitivity_demand_half": 0.5, "sensitivity_demand_double": 2.0}.items():
        for r in _trains(name):
            assert load_task_config(r.kwargs["task_conf"])[0].demand_scale == scale
            assert r.kwargs["train_days"] == 1200
    for r in _trains("sensitivity_global_obs"):
        assert load_env_config(r.kwargs["env_conf"])[0].observations == "global_previous_agents"


def test_runs_shared_between_entries_are_the_same_experiment():
    """An id in two entries is one folder in a shared results dir (the suite skips it the second
    time), so both entries must mean the same run by it."""
    seen: dict[str, tuple] = {}
    for path in sorted(SUITES.glob("*.json")):
        for run in load_suite(path).runs:
            key = (run.kind, tuple(sorted((k, str(v)) for k, v in run.kwargs.items())))
            assert seen.setdefault(run.exp_id, key) == key, f"{path.name}: {run.exp_id} differs"


@pytest.mark.real_networks
def test_every_catalogue_network_is_a_shared_urb_network(real_networks_dir):
    for name in CATALOGUE:
        for run in load_suite(find_config("suites", name)).runs:
            net = run.kwargs["net"]
            assert (real_networks_dir / net / f"{net}.net.xml").is_file(), (name, net)


def test_suite_list_names_every_shipped_suite(capsys):
    from urb_jax.commands.cli import main

    assert main(["suite", "--list"]) == 0
    out = capsys.readouterr().out
    for name in [*CATALOGUE, "nine_networks"]:
        assert f"\n{name} " in f"\n{out}"
    assert "15 train runs (73 seed folders), 6 baselines" in out  # scenario1: 15 x 5 seeds, Ingolstadt QMIX 3
    assert main(["suite"]) == 2  # no suite named: the list, and exit 2
