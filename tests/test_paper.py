"""docs/paper.md (`urb-jax suite --paper`): the paper's numbers as data, each with its source, and
the generator that puts our finished catalogue runs beside them and judges each paper conclusion."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pytest
from support.catalogue import CATALOGUE, SUITES

from urb_jax.core.errors import ConfigError
from urb_jax.reporting.leaderboard import collect_folders
from urb_jax.reporting.paper import COLUMNS, EntryResults, load_paper_numbers, paper_file, paper_markdown
from urb_jax.reporting.urb_names import baseline_names, train_names
from urb_jax.runs.suite import SuiteRun, folders_left, load_suite, remaining
from urb_jax.runs.suite import status as status_of


def test_the_data_file_covers_exactly_the_papers_catalogue():
    entries = load_paper_numbers()["entries"]
    assert list(entries) == CATALOGUE  # the page follows the catalogue's order
    assert all((SUITES / f"{e}.json").is_file() for e in entries)
    # every network a paper table names is one the entry's suite runs
    for entry, e in entries.items():
        nets = {r.kwargs["net"] for r in load_suite(SUITES / f"{entry}.json").runs}
        assert {t["network"] for t in e.get("tables", [])} <= nets, entry


def test_every_number_has_a_source_and_not_found_entries_have_none():
    data = load_paper_numbers()
    label = re.compile(r"(tab|sec|fig):")
    for entry, e in data["entries"].items():
        if e["status"] != "found":
            assert "tables" not in e and e["notes"], entry
            unsourced = re.search(r"(?<![\d.])\d\.\d\d(?!\d)", e["notes"])
            assert not unsourced, f"{entry}: a number without a source"
            assert all(label.match(c["source"]) for c in e.get("claims", [])), entry
            continue
        for t in e["tables"]:
            assert label.match(t["source"]) and t["caption"], (entry, t["network"])
            for alg, row in t["rows"].items():
                assert set(row["values"]) <= set(COLUMNS) and set(row.get("sd", {})) <= set(row["values"])
                assert all(label.match(c["source"]) for c in row["claims"]), (entry, alg)
    # tab:kpis: every RL cell with its sd, over five runs; the baselines without
    s1 = {t["network"]: t for t in data["entries"]["scenario1"]["tables"]}
    rl = ("ippo", "iql", "mappo", "qmix")
    for t in s1.values():
        assert t["runs"] == 5 and t["source"] == "tab:kpis"
        for alg in rl:
            assert set(t["rows"][alg]["sd"]) == set(COLUMNS) - {"t_pre", "WR", "delta_pct"}, alg
        for alg in ("human", "aon", "random"):
            assert "sd" not in t["rows"][alg] and t["rows"][alg]["runs"] is None, alg
    # independent of the file: the published t_pre and AON t_CAV the project recorded in docs/metrics.md
    nets = ("saint_arnoult", "provins", "ingolstadt_custom")
    assert [s1[n]["rows"]["human"]["values"]["t_pre"] for n in nets] == [3.15, 2.80, 4.21]
    assert [s1[n]["rows"]["aon"]["values"]["t_CAV"] for n in nets] == [3.01, 2.76, 4.37]
    # the paper's 5-run table differs from URB's README (3 runs) in 77 of its 108 RL cells
    differ = [(n, a, c) for n in nets for a in rl for c, v in s1[n]["rows"][a]["values"].items()
              if c != "t_pre" and v != s1[n]["readme"]["values"][a][c]]
    assert len(differ) == 77
    sa, ing = s1["saint_arnoult"], s1["ingolstadt_custom"]
    assert (sa["rows"]["iql"]["values"]["t_CAV"], sa["readme"]["values"]["iql"]["t_CAV"]) == (3.53, 3.49)
    assert sa["rows"]["qmix"]["values"]["WR"] == 80 and sa["rows"]["qmix"]["sd"]["t_CAV"] == 0.206
    assert (ing["rows"]["qmix"]["values"]["t_CAV"], ing["readme"]["values"]["qmix"]["t_CAV"]) == (4.87, 4.55)


def _edited(tmp_path: Path, edit) -> Path:
    data = json.loads(paper_file().read_text())
    edit(data)
    path = tmp_path / "paper.json"
    path.write_text(json.dumps(data))
    return path


def _s1(d: dict, i: int) -> dict:
    return d["entries"]["scenario1"]["tables"][i]


@pytest.mark.parametrize("edit, message", [
    (lambda d: _s1(d, 0)["rows"]["ippo"].update(claims=[{"claim": ["t_CAV", "<", "t_pre"],
                                                         "source": "tab:kpis"}]),
     r"rows\.ippo: claim .* does not hold on the paper's own numbers"),
    (lambda d: _s1(d, 1).pop("source"), r"tables\[1\]: a table needs .*'source'"),
    (lambda d: d["entries"]["demo_nemours_malicious"].update(tables=[{}]),
     r"entries\.demo_nemours_malicious: 'figure only' has no tables"),
    (lambda d: _s1(d, 2)["rows"]["iql"]["claims"][0].pop("source"), r"rows\.iql: claim .* has no 'source'"),
])
def test_a_bad_data_file_is_refused_naming_the_field(tmp_path, edit, message):
    path = _edited(tmp_path, edit)
    with pytest.raises(ConfigError, match=message) as err:
        load_paper_numbers(path)
    assert str(path) in str(err.value) and "Fix:" in str(err.value)


def _run(root: Path, name: str, names: dict, network: str, task: str, **metrics: float) -> Path:
    folder = root / name
    (folder / "metrics").mkdir(parents=True)
    cfg = {"network": network, "env_config": "config1", "task_config": task, "exp_type": "normal",
           "env_seed": 42, "status": "done", **names}
    (folder / "exp_config.json").write_text(json.dumps(cfg))
    pd.DataFrame([metrics]).to_csv(folder / "metrics" / "BenchmarkMetrics.csv", index=False)
    return folder


@pytest.fixture
def scenario1_partly_run(tmp_path):
    """Scenario 1 on St. Arnoult with IPPO (2 seeds) and AON finished, nothing else."""
    ippo = train_names("ippo", "hybrid", "default", 6000, "config1")
    # trained with whole rounds: 10 rounds of 640 surrogate + 4 SUMO days for the 6,000 asked
    ippo |= {"sumo_training_days": 40, "surrogate_training_days": 6400, "train_args": {"train_days": 6000}}
    # duration: IPPO's CAVs slower than as humans (as in the paper); travel time: faster (unlike it)
    folders = [_run(tmp_path, f"s1_saint_arnoult_ippo_s{s}", ippo, "saint_arnoult", "config1",
                    t_pre=3.19, t_CAV=t, t_pre_duration=3.16, t_CAV_duration=d, winrate=float(t < 3.19))
               for s, (t, d) in enumerate([(3.17, 3.30), (3.15, 3.34)])]
    folders.append(_run(tmp_path, "saint_arnoult_aon", baseline_names("aon", 200), "saint_arnoult", "config1",
                        t_pre=3.19, t_CAV=3.05, t_pre_duration=3.16, t_CAV_duration=3.02, winrate=1.0))
    return folders


def _section(text: str, entry: str) -> str:
    start = text.index(f"## `{entry}`")
    return text[start:text.find("\n## ", start + 1)]


def _claim(text: str, row: str, claim: str) -> str:
    """The judged line of one claim of one row (the row's first table on the page)."""
    block = text[text.index(f"- **{row}** (paper:"):]
    return next(line for line in block.splitlines()[1:] if line.startswith(f"  - {claim} ["))


def test_the_page_puts_ours_beside_the_papers_rows_and_judges_each_conclusion(scenario1_partly_run):
    paper = load_paper_numbers()
    results = [EntryResults("scenario1", "Scenario 1", collect_folders(scenario1_partly_run), 21, 2, 5),
               EntryResults("scenario2", "Scenario 2", pd.DataFrame(), 7, 0, 5)]
    text = paper_markdown(results, paper, "# header")
    lines = text.splitlines()
    # the paper's IPPO row with its stds (tab:kpis), the README's older numbers where they differ, then
    # ours in both measures (mean ± sample std of the two seeds) and each cell's verdict against the paper
    i = lines.index("| **IPPO** | paper [tab:kpis] | 5 |  | 3.15 | 3.28 (0.004) | 3.33 (0.013) "
                    "| 3.25 (0.008) | 0.63 (0.015) | 0.13 (0.004) | 1.38 (0.034) | -0.24 (0.067) "
                    "| 0.06 (0.004) | 0 |")
    assert lines[i + 1] == "|  | README | 3 |  |  |  | 3.34 | 3.24 | 0.6 | 0.12 | 1.33 | -0.31 | 0.05 |  |"
    # its training days, marked: 6,440 trained of 6,000 asked (the legend says what the mark means)
    days = "40 SUMO + 6,400 surrogate = 6,440 (6,000 asked) †"
    assert lines[i + 2].startswith(f"|  | ours, SUMO duration | 2 | {days} | 3.1600 ± 0.0000 | n/a | "
                                   "3.3200 ± 0.0283 |")
    assert lines[i + 2].endswith("| 0 (0/2) |")  # WR in duration: neither seed beat its t_pre
    assert lines[i + 3].startswith("|  | ours, travel time | 2 |  | 3.1900 ± 0.0000 | n/a | "
                                   "3.1600 ± 0.0141 |")
    assert lines[i + 3].endswith("| 100 (2/2) |")  # in travel time both did
    assert lines[i + 4].startswith("|  | ours vs paper |  |  | equal | · | tie |")  # t_CAV: 3.32 vs 3.33
    aon = lines.index(next(line for line in lines if line.startswith("| **AON** | paper")))
    assert lines[aon + 1].startswith("|  | ours, SUMO duration | 1 | none (a baseline: no training) |")
    assert "† trained more days than asked: the run's budget was rounded up to whole rounds" in text
    # per-seed differences (0.14, 0.18): mean 0.16, se 0.02, t = 8 on 1 df: one-sided p = 0.040 -> holds;
    # in travel time (-0.02, -0.04): t = -3, p = 0.102 either way -> a tie
    pre = _claim(text, "IPPO", "t_CAV > t_pre")
    assert "**holds** (difference +0.1600" in pre and "one-sided p = 0.040" in pre
    assert "; in travel time tie (difference -0.0300" in pre
    assert "**holds** (difference +0.3000" in _claim(text, "IPPO", "t_CAV > AON t_CAV")  # AON: one run
    assert "**tie** (0 of 2 runs, 95% CI [0%, 84%]" in _claim(text, "IPPO", "WR < 50%")
    assert "Why" not in pre
    # one run on each side: by value, and the line says so
    assert "**holds** (difference -0.1400; no spread: by value)" in _claim(text, "AON", "t_CAV < t_pre")
    # QMIX did not run, Provins did not run, Scenario 2 did not run
    assert "**not comparable** (not run yet (QMIX))" in _claim(text, "QMIX", "t_CAV > t_pre")
    provins = text[text.index("### Provins"):text.index("### Ingolstadt")]
    assert "not run yet" in provins and "ours, SUMO duration" not in provins
    s2 = text[text.index("## `scenario2`"):]
    assert "Ours: not run yet" in s2
    # the summary counts every conclusion, and says why some cannot be compared
    summary = text[text.index("## Summary"):text.index("## `scenario1`")]
    assert "cannot be compared here" in summary and "ddof=1" in summary and "Clopper-Pearson" in summary
    assert "`scenario1`: not run yet (QMIX)" in summary


def test_the_control_splits_the_gap_into_implementation_and_surrogate(tmp_path):
    """Paper IQL 3.53 (sd 0.104, 5 runs); ours in SUMO only 3.00, 3.02; ours hybrid 3.01, 3.05 (SUMO
    duration). Implementation: +0.52, far outside the seed spread; surrogate: -0.02 with a Welch
    interval over 1.5 df that covers 0, so a tie."""
    sumo = train_names("iql", "sumo", "default", 6000, "config1")
    hyb = train_names("iql", "hybrid", "default", 6000, "config1")
    control = [_run(tmp_path / "c", f"sumo_s1_saint_arnoult_iql_s{s}", sumo, "saint_arnoult", "config1",
                    t_pre=3.19, t_CAV=d + 0.03, t_pre_duration=3.16, t_CAV_duration=d, winrate=1.0)
               for s, d in enumerate([3.00, 3.02])]
    hybrid = [_run(tmp_path / "h", f"s1_saint_arnoult_iql_s{s}", hyb, "saint_arnoult", "config1",
                   t_pre=3.19, t_CAV=d + 0.03, t_pre_duration=3.16, t_CAV_duration=d, winrate=1.0)
              for s, d in enumerate([3.01, 3.05])]
    results = [EntryResults("scenario1", "Scenario 1", collect_folders(hybrid), 21, 1, 5),
               EntryResults("scenario1_sumo", "control", collect_folders(control), 4, 1, 5)]
    text = paper_markdown(results, load_paper_numbers(), "# header")
    split = _section(text, "scenario1_sumo").split("### The gap to the paper")[1].splitlines()
    row = next(line for line in split if line.startswith("| **IQL** |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[:3] == ["**IQL**", "saint_arnoult", "3.53 (0.104)"]
    assert cells[3].startswith("3.0100 ± 0.0141 [") and cells[3].endswith("(2)")
    assert cells[4].startswith("3.0300 ± 0.0283 [")
    assert cells[5].startswith("+0.5200 [+0.3") and cells[5].endswith("p < 0.001")  # the implementation
    assert cells[6].startswith("-0.0200 [") and cells[6].endswith("**tie**")  # the surrogate
    assert cells[7] == cells[8] == "2/2 [16%, 100%]"  # Clopper-Pearson: 0.025 ** (1 / 2)
    qmix = next(line for line in split if line.startswith("| **QMIX** |"))
    assert "not run yet" in qmix


def _faster_ippo(root: Path) -> list[Path]:
    """IPPO on St. Arnoult faster than its humans in every seed (unlike the paper), and AON."""
    ippo = train_names("ippo", "hybrid", "default", 6000, "config1")
    folders = [_run(root, f"s1_saint_arnoult_ippo_s{s}", ippo, "saint_arnoult", "config1", t_pre=3.19,
                    t_CAV=d + 0.03, t_pre_duration=3.16, t_CAV_duration=d, winrate=1.0)
               for s, d in enumerate([3.00, 3.01, 3.02])]
    folders.append(_run(root, "saint_arnoult_aon", baseline_names("aon", 200), "saint_arnoult", "config1",
                        t_pre=3.19, t_CAV=3.05, t_pre_duration=3.16, t_CAV_duration=3.02, winrate=1.0))
    return folders


def test_a_contradicted_claim_says_why_or_that_it_is_not_established(tmp_path):
    paper = load_paper_numbers()
    runs = collect_folders(_faster_ippo(tmp_path / "runs"))
    text = paper_markdown([EntryResults("scenario1", "S1", runs, 21, 2, 5)], paper, "")
    pre = _claim(text, "IPPO", "t_CAV > t_pre")
    why = paper["entries"]["scenario1"]["why_not"]["ippo: t_CAV > t_pre"]
    assert "**fails** (difference -0.1500" in pre and pre.endswith("*Why ours differ:* " + why)
    assert "`scenario1` saint_arnoult IPPO: t_CAV > t_pre [tab:kpis caption]" in text  # in the summary
    # without the entry's explanations, the page says the reason is not established
    path = _edited(tmp_path, lambda d: d["entries"]["scenario1"].pop("why_not"))
    text = paper_markdown([EntryResults("scenario1", "S1", runs, 21, 2, 5)], load_paper_numbers(path), "")
    assert _claim(text, "IPPO", "t_CAV > t_pre").endswith("*Why ours differ:* not established yet.")


def test_an_explanation_for_a_claim_no_row_makes_is_refused(tmp_path):
    vdn = {"vdn: t_CAV > t_pre": "VDN is not in the paper's table"}
    path = _edited(tmp_path, lambda d: d["entries"]["scenario1"]["why_not"].update(vdn))
    message = r"scenario1\.why_not: \['vdn: t_CAV > t_pre'\] are not claims"
    with pytest.raises(ConfigError, match=message) as err:
        load_paper_numbers(path)
    assert str(path) in str(err.value) and "Fix:" in str(err.value)


def test_a_row_that_names_a_missing_row_says_which(scenario1_partly_run):
    """IPPO ran but AON did not: the AON comparison is 'not run yet (AON)', the t_pre one is judged."""
    paper = load_paper_numbers()
    ippo_only = collect_folders(scenario1_partly_run[:2])
    text = paper_markdown([EntryResults("scenario1", "S1", ippo_only, 21, 1, 5)], paper, "")
    assert "**holds**" in _claim(text, "IPPO", "t_CAV > t_pre")
    assert "**not comparable** (not run yet (AON))" in _claim(text, "IPPO", "t_CAV > AON t_CAV")


def test_the_per_seed_values_a_ledger_row_lacks_are_not_judged(scenario1_partly_run):
    runs = collect_folders(scenario1_partly_run).drop(columns=["t_CAV_duration"])
    text = paper_markdown([EntryResults("scenario1", "S1", runs, 21, 2, 5)], load_paper_numbers(), "")
    assert "**not comparable** (per-seed values not recorded)" in _claim(text, "IPPO", "t_CAV > t_pre")


@pytest.mark.parametrize("variant", ["demand_half", "demand_double", "global_obs", "original"])
def test_the_sensitivity_entries_run_the_papers_iql_and_mappo_for_exactly_its_1200_days(variant):
    """tab:sensitivity_kpis: IQL and MAPPO as in the main experiments, 1,200 training days; the
    suites' rounds (one iteration of URB's 20 days in 14 envs, plus 20 SUMO days) add up to 1,200."""
    from urb_jax.core.configio import in_section
    from urb_jax.runs.urb_configs import run_overrides
    from urb_jax.training.hybrid.plan import load_hybrid_config, plan_rounds

    runs = [r for r in load_suite(SUITES / f"sensitivity_{variant}.json").runs if r.kind == "train"]
    assert sorted(r.kwargs["alg"] for r in runs) == ["iql", "mappo"]
    for run in runs:
        assert run.kwargs["alg_conf"] == "config1" and run.kwargs["train_days"] == 1200
        given = [*run.kwargs["overrides"], "hybrid.train_days=1200"]
        cfg, _ = load_hybrid_config("default", in_section(run_overrides(given), "hybrid"))
        plan = plan_rounds(cfg, "hybrid", days_per_iter=20)  # URB's agent_frames_per_batch, config1
        assert plan.n_rounds * (plan.surrogate_days + plan.sumo_days) == 1200, run.exp_id
        cooperative = run.kwargs["task_conf"] == "config2" or "task.av_behavior=cooperative" in given
        assert cooperative == (run.kwargs["alg"] == "mappo"), run.exp_id  # scenario1's tasks


def test_suite_paper_writes_the_page_from_a_results_folder(tmp_path, scenario1_partly_run, monkeypatch):
    """`urb-jax suite --paper`: finished runs found by the catalogue's run ids, the suite's figures
    copied beside the page and linked relative to it, every other entry 'not run yet'."""
    import urb_jax.runs.suite as suite
    from urb_jax.commands.cli import main

    def fake_report(title, folders, out_dir, preamble=""):  # the suite's report needs day records
        (Path(out_dir) / "figures").mkdir(parents=True)
        (Path(out_dir) / "figures" / "saint_arnoult_ippo_config1.png").write_bytes(b"png bytes")
        return Path(out_dir) / "README.md"

    monkeypatch.setattr(suite, "write_report", fake_report)
    ippo = train_names("ippo", "hybrid", "default", 6000, "config1")
    for seed in (2, 3, 4):  # the suite's IPPO run trains seeds 0-4 together: it is done when all are
        _run(tmp_path, f"s1_saint_arnoult_ippo_s{seed}", ippo, "saint_arnoult", "config1", t_pre=3.19,
             t_CAV=3.2, t_pre_duration=3.16, t_CAV_duration=3.3, winrate=0.0)
    out = tmp_path / "docs" / "paper.md"
    assert main(["suite", "--paper", "--results-dir", str(tmp_path), "--out", str(out)]) == 0
    text = out.read_text()
    assert "| `scenario1` | found | 2 of 21 runs finished |" in text  # IPPO's 5 seeds are one run, unfinished
    assert "| `adjusted_iql_ippo` | found | 1 of 12 runs finished |" in text  # it shares the AON run
    assert "| `scenario2` | found | not run yet |" in text
    # a partly run entry names the 19 runs it has left, not the two finished (IPPO, AON)
    left = next(line for line in text.splitlines() if line.startswith("Not finished yet:"))
    assert "`s1_saint_arnoult_iql`" in left and "`s1_ingolstadt_custom_qmix`" in left
    assert "`s1_saint_arnoult_ippo`" not in left and "`saint_arnoult_aon`" not in left
    assert left.count("`, `") == 18
    # the figure is copied next to the page and linked there: the page's links hold in the repository
    assert "![saint_arnoult_ippo_config1](paper_figures/scenario1/saint_arnoult_ippo_config1.png)" in text
    copied = out.parent / "paper_figures" / "scenario1" / "saint_arnoult_ippo_config1.png"
    assert copied.read_bytes() == b"png bytes"
    aon = "- **AON** (paper: AON CAVs faster than the drivers were as humans):\n  - t_CAV < t_pre [tab:kpis]"
    assert aon + ": **holds**" in text
    assert not list(out.parent.glob(".*"))  # written atomically: no temporary file left beside it


def _fake_report(title, folders, out_dir, preamble=""):
    """The suite's report needs day records: one figure per network of the finished folders."""
    (Path(out_dir) / "figures").mkdir(parents=True, exist_ok=True)
    for net in {json.loads((Path(f) / "exp_config.json").read_text())["network"] for f in folders}:
        (Path(out_dir) / "figures" / f"{net}.png").write_bytes(net.encode())
    return Path(out_dir) / "README.md"


def test_the_page_names_its_folders_relative_to_where_it_was_run(tmp_path, monkeypatch):
    """The page is committed and read elsewhere: an absolute --results-dir is written relative to
    the folder the command ran in, and nothing on the page names this machine's folders."""
    from urb_jax.commands.cli import main

    (tmp_path / "runs" / "catalogue").mkdir(parents=True)
    work = tmp_path / "checkout"
    work.mkdir()
    monkeypatch.chdir(work)
    out = work / "docs" / "paper.md"
    assert main(["suite", "--paper", "--results-dir", str(tmp_path / "runs" / "catalogue"),
                 "--out", str(out)]) == 0
    text = out.read_text()
    header = ("Generated by `urb-jax suite --paper --results-dir ../runs/catalogue` from the finished runs "
              "under `../runs/catalogue`\nand the runs of earlier generations recorded in `paper_runs.json`")
    assert header in text
    assert str(tmp_path) not in text and not re.search(r"[Ss]ession \d", text)


def test_the_page_keeps_the_runs_of_earlier_generations(tmp_path, monkeypatch, capsys):
    """A catalogue outlives a machine: runs finished in one results folder (another machine) stay on
    the page, through its ledger, when it is generated again from another folder with other runs; a
    run finished again replaces its recorded numbers; figures made before stay linked; the suite
    on the second machine skips the runs the ledger records."""
    import urb_jax.runs.suite as suite
    from urb_jax.commands.cli import main

    monkeypatch.setattr(suite, "write_report", _fake_report)
    drawn: dict[str, pd.DataFrame] = {}  # each entry's figure against the humans: what it drew
    monkeypatch.setattr(suite, "against_humans_figure",
                        lambda points, path: drawn.__setitem__(path.parent.name, points) or path)
    ippo = train_names("ippo", "hybrid", "default", 6000, "config1")
    first, second, docs = tmp_path / "machine1", tmp_path / "machine2", tmp_path / "docs"
    for seed in range(5):
        _run(first, f"s1_saint_arnoult_ippo_s{seed}", ippo, "saint_arnoult", "config1", t_pre=3.19,
             t_CAV=3.2 + 0.01 * seed, t_pre_duration=3.16, t_CAV_duration=3.3, winrate=0.0)
    _run(first, "saint_arnoult_aon", baseline_names("aon", 200), "saint_arnoult", "config1",
         t_pre=3.19, t_CAV=3.05, t_pre_duration=3.16, t_CAV_duration=3.02, winrate=1.0)
    out = docs / "paper.md"
    assert main(["suite", "--paper", "--results-dir", str(first), "--out", str(out)]) == 0
    page1 = out.read_text()
    ledger = json.loads((docs / "paper_runs.json").read_text())["runs"]
    # scenario1's IPPO (5 seed folders) and AON, and the adjusted table's AON (the same run, its own row)
    assert sorted((r["entry"], r["exp_id"]) for r in ledger) == sorted(
        [("scenario1", f"s1_saint_arnoult_ippo_s{s}") for s in range(5)]
        + [("scenario1", "saint_arnoult_aon"), ("adjusted_iql_ippo", "saint_arnoult_aon")])
    assert not any("folder" in r for r in ledger) and str(first) not in (docs / "paper_runs.json").read_text()
    ippo_rows = [line for line in _section(page1, "scenario1").splitlines()
                 if line.startswith("|  | ours, ") and "| 5 |" in line and "| n/a |" in line]  # not Human's
    assert len(ippo_rows) == 2

    # machine 2: provins AON, and St. Arnoult's AON again with other numbers; machine 1's folder is gone
    _run(second, "provins_aon", baseline_names("aon", 200), "provins", "config1",
         t_pre=2.84, t_CAV=2.80, t_pre_duration=2.81, t_CAV_duration=2.76, winrate=1.0)
    _run(second, "saint_arnoult_aon", baseline_names("aon", 200), "saint_arnoult", "config1",
         t_pre=3.19, t_CAV=3.04, t_pre_duration=3.16, t_CAV_duration=3.01, winrate=1.0)
    assert main(["suite", "--paper", "--results-dir", str(second), "--out", str(out)]) == 0
    page2 = out.read_text()
    assert "| `scenario1` | found | 3 of 21 runs finished |" in page2  # IPPO, AON here and Provins AON
    for line in ippo_rows:  # machine 1's IPPO numbers, read from the ledger, unchanged
        assert line in page2
    aon = _claim(page2, "AON", "t_CAV < t_pre")
    assert "difference -0.1500" in aon  # St. Arnoult's AON: machine 2's numbers replace the recorded ones
    provins = page2[page2.index("### Provins"):page2.index("### Ingolstadt")]
    assert "2.7600" in provins
    figures = sorted(p.name for p in (docs / "paper_figures" / "scenario1").iterdir())
    assert figures == ["provins.png", "saint_arnoult.png"]  # machine 1's figure kept, machine 2's added
    # the figure against the humans draws every shown run: machine 1's IPPO (the ledger's) too
    points = drawn["scenario1"].set_index(["network", "run"])
    assert points.loc[("saint_arnoult", "ippo"), "seeds"] == 5
    assert points.loc[("saint_arnoult", "ippo"), "mean"] == pytest.approx(3.22 - 3.19)
    assert points.loc[("provins", "baseline_aon"), "mean"] == pytest.approx(2.80 - 2.84)
    assert (docs / "paper_figures" / "scenario1" / "saint_arnoult.png").read_bytes() == b"saint_arnoult"
    for name in ("provins", "saint_arnoult"):
        assert f"paper_figures/scenario1/{name}.png" in page2
    assert len(json.loads((docs / "paper_runs.json").read_text())["runs"]) == 9

    # machine 2 continues the catalogue: the ledger's runs count as finished (elsewhere) and are skipped
    ledger = str(docs / "paper_runs.json")
    args = ["suite", "scenario1", "--only", "s1_saint_arnoult_ippo,saint_arnoult_aon,s1_provins_ippo",
            "--results-dir", str(second), "--ledger", ledger, "--no-progress"]
    capsys.readouterr()
    assert main([*args, "--status"]) == 0
    status = capsys.readouterr().out
    for run, state in (("s1_saint_arnoult_ippo", "recorded"), ("saint_arnoult_aon", "done"),
                       ("s1_provins_ippo", "new")):
        assert re.search(rf"{run} +{state}", status)
    assert "3 runs: 1 done, 1 recorded, 0 running, 0 stopped, 1 new" in status
    assert main([*args, "--status", "--ledger", "none"]) == 0
    assert re.search(r"s1_saint_arnoult_ippo +new", capsys.readouterr().out)
    assert main(["suite", "--status", "--results-dir", str(second), "--ledger", ledger]) == 0  # every entry
    overview = capsys.readouterr().out
    assert re.search(r"^scenario1 +21 runs: 2 done, 1 recorded, 0 running, 0 stopped, 18 new$", overview,
                     re.MULTILINE)
    assert re.search(r"^sensitivity_global_obs +3 runs: 0 done, 0 recorded, 0 running, 0 stopped, 3 new$",
                     overview, re.MULTILINE)
    args[3] = "s1_saint_arnoult_ippo,saint_arnoult_aon"
    assert main(args) == 0  # nothing to simulate: both skipped
    out_lines = capsys.readouterr().out
    assert "s1_saint_arnoult_ippo (train): finished elsewhere (in the page's ledger), skipped" in out_lines
    assert not any(p.name.startswith("s1_saint_arnoult_ippo") for p in second.iterdir())


def test_a_broken_ledger_is_refused_naming_the_file(tmp_path, capsys):
    from urb_jax.commands.cli import main

    (tmp_path / "paper_runs.json").write_text('{"runs": [{"exp_id": "x"}]}')
    rc = main(["suite", "--paper", "--results-dir", str(tmp_path), "--out", str(tmp_path / "paper.md")])
    err = capsys.readouterr().err
    assert rc == 2 and str(tmp_path / "paper_runs.json") in err and "Fix:" in err
    assert not (tmp_path / "paper.md").exists()


def test_a_generation_that_would_drop_finished_runs_is_refused(tmp_path, capsys, monkeypatch):
    """A page made before the ledger existed shows finished runs that no results
    folder here holds: generating it again from an empty folder would lose them, so it is refused
    (exit 2, naming the entries and the fix) and the page is left as it was; --allow-fewer writes."""
    import urb_jax.runs.suite as suite
    from urb_jax.commands.cli import main

    monkeypatch.setattr(suite, "write_report", _fake_report)
    page = tmp_path / "docs" / "paper.md"
    page.parent.mkdir()
    committed = ("# The URB paper next to urb-jax\n\n| entry | paper's numbers | ours |\n|---|---|---|\n"
                 "| `scenario1` | found | not run yet |\n"
                 "| `sensitivity_demand_half` | found | 3 of 3 runs finished |\n")
    page.write_text(committed)
    args = ["suite", "--paper", "--results-dir", str(tmp_path / "empty"), "--out", str(page)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "sensitivity_demand_half (3 -> 0)" in err and "--allow-fewer" in err and str(page) in err
    assert page.read_text() == committed and not (page.parent / "paper_runs.json").exists()
    assert main([*args, "--allow-fewer"]) == 0
    assert "| `sensitivity_demand_half` | found | not run yet |" in page.read_text()


def test_the_summary_says_which_seed_runs_the_ledger_can_say_how_they_were_made():
    import pandas as pd

    from urb_jax.runs.suite import _FINISHED, _provenance_cell

    made = {"commit": "abc", "wall_time_s": 12.0}
    assert _provenance_cell(pd.DataFrame({"provenance": [made, made]})) == "every seed run (2)"
    mixed = _provenance_cell(pd.DataFrame({"provenance": [made, float("nan"), None]}))
    assert mixed.startswith("1 of 3 seed runs; the other 2 finished before the ledger kept provenance")
    assert _provenance_cell(pd.DataFrame({"exp_id": ["a"]})).startswith("none of 1 seed runs")
    # the refusal to drop finished runs reads pages with and without the provenance column
    page = ("| `scenario1` | found | 21 of 21 runs finished | every seed run (79) |\n"
            "| `scenario2` | found | 7 of 7 runs finished |\n")
    assert [(m[1], m[2]) for m in _FINISHED.finditer(page)] == [("scenario1", "21"), ("scenario2", "7")]


def test_the_finished_seeds_of_an_unfinished_run_outlive_their_machine(tmp_path, monkeypatch, capsys):
    """A run's seeds can take longer than a machine lives (Ingolstadt's QMIX: 2.5 h a seed): each seed
    finished goes to the ledger at once, though its run is not shown until all its seeds are; the
    next machine runs only the seeds the ledger lacks, and the page then shows the run whole."""
    import urb_jax.runs.suite as suite
    from urb_jax.commands.cli import main

    monkeypatch.setattr(suite, "write_report", _fake_report)
    drawn: dict[str, pd.DataFrame] = {}  # each entry's figure against the humans: what it drew
    monkeypatch.setattr(suite, "against_humans_figure",
                        lambda points, path: drawn.__setitem__(path.parent.name, points) or path)
    ippo = train_names("ippo", "hybrid", "default", 6000, "config1")
    first, second, docs = tmp_path / "machine1", tmp_path / "machine2", tmp_path / "docs"
    for seed in (0, 1):  # machine 1 ends after 2 of the run's 5 seeds
        _run(first, f"s1_saint_arnoult_ippo_s{seed}", ippo, "saint_arnoult", "config1", t_pre=3.19,
             t_CAV=3.2, t_pre_duration=3.16, t_CAV_duration=3.30 + 0.01 * seed, winrate=0.0)
    (first / "s1_saint_arnoult_ippo_s2").mkdir()  # a seed stopped there: lost with the machine
    out = docs / "paper.md"
    assert main(["suite", "--paper", "--results-dir", str(first), "--out", str(out)]) == 0
    page1 = out.read_text()
    assert "| `scenario1` | found | not run yet |" in page1  # the run is not shown with 2 seeds ...
    assert "(kept in the ledger, shown once their run is): `s1_saint_arnoult_ippo_s0`, " \
           "`s1_saint_arnoult_ippo_s1`." in page1  # ... but its finished seeds are kept
    ledger = json.loads((docs / "paper_runs.json").read_text())["runs"]
    assert sorted(r["exp_id"] for r in ledger) == ["s1_saint_arnoult_ippo_s0", "s1_saint_arnoult_ippo_s1"]

    # machine 2: the suite would run seeds 2-4 only
    args = ["suite", "scenario1", "--only", "s1_saint_arnoult_ippo", "--results-dir", str(second),
            "--ledger", str(docs / "paper_runs.json")]
    capsys.readouterr()
    assert main([*args, "--status"]) == 0
    status = capsys.readouterr().out
    assert re.search(r"s1_saint_arnoult_ippo +new", status)
    assert "seed(s) 0, 1: finished elsewhere (the ledger)" in status
    planned = [SuiteRun("train", "s1_saint_arnoult_ippo", {"alg": "ippo", "seeds": [0, 1, 2, 3, 4]})][0]
    recorded = {"s1_saint_arnoult_ippo_s0", "s1_saint_arnoult_ippo_s1"}
    left = folders_left(second, planned, recorded)
    assert left == [f"s1_saint_arnoult_ippo_s{s}" for s in (2, 3, 4)]
    assert remaining(planned, left).kwargs["seeds"] == [2, 3, 4]
    for seed in (2, 3, 4):  # ... and it finishes them
        _run(second, f"s1_saint_arnoult_ippo_s{seed}", ippo, "saint_arnoult", "config1", t_pre=3.19,
             t_CAV=3.2, t_pre_duration=3.16, t_CAV_duration=3.30 + 0.01 * seed, winrate=0.0)
    assert status_of(second, planned, recorded) == "recorded"
    assert main(["suite", "--paper", "--results-dir", str(second), "--out", str(out)]) == 0
    page2 = out.read_text()
    assert "| `scenario1` | found | 1 of 21 runs finished |" in page2
    assert "kept in the ledger, shown once" not in page2
    [duration] = [line for line in _section(page2, "scenario1").splitlines()
                  if line.startswith("|  | ours, SUMO duration |") and "| 5 |" in line and "| n/a |" in line]
    assert "3.3200 ± 0.0158" in duration  # all five seeds (3.30 ... 3.34): mean, sample std (ddof=1)
    assert len(json.loads((docs / "paper_runs.json").read_text())["runs"]) == 5


def test_a_cost_cell_says_why_it_is_not_judged():
    """A paper cost cell is never compared by value: a hybrid run's row says it is hybrid (its cost
    counts surrogate days), a SUMO-only row says the published definition differs."""
    from urb_jax.reporting.paper import WHY_COST, judge_cell
    from urb_jax.reporting.verdicts import NOT_COMPARABLE

    table = {"rows": {"iql": {"values": {"c_CAV": 1.5}}}, "runs": 3}
    hybrid = pd.DataFrame({"c_CAV": [1.0], "sumo_training_days": [40], "surrogate_training_days": [5960]})
    sumo = hybrid.assign(sumo_training_days=6000, surrogate_training_days=0)
    on_hybrid, on_sumo = (judge_cell(table, "iql", "c_CAV", {"iql": rows}) for rows in (hybrid, sumo))
    assert on_hybrid.kind == on_sumo.kind == NOT_COMPARABLE
    assert on_hybrid.detail == "not comparable: hybrid (40 SUMO of 6000 training days)"
    assert on_sumo.detail == WHY_COST


def _seed_rows(alg: str, values: list[float], prefix: str) -> list[dict]:
    return [{"network": "saint_arnoult", "algorithm": alg, "alg": alg, "exp_id": f"{prefix}_{alg}_s{i}",
             "t_CAV_duration": v, "t_pre_duration": 3.1585} for i, v in enumerate(values)]


def test_the_implementation_share_is_split_into_urbs_wiring_and_what_is_left():
    """scenario1_sumo's page section: ours on URB's wiring against ours (the wiring's share) and the
    paper against ours on URB's wiring (what is left), each a Welch difference checked with scipy."""
    from scipy import stats

    from urb_jax.reporting.paper import wiring_markdown

    paper = load_paper_numbers()["entries"]["scenario1_sumo"]
    assert paper["wiring"] == "urb_wiring"
    wiring = [3.13, 3.79, 3.77, 3.59, 3.78]  # IQL on URB's frames and raw seconds
    ours = [3.015, 3.013, 3.018, 3.028, 3.014]
    lines = wiring_markdown(paper, pd.DataFrame(_seed_rows("iql", ours, "s1")),
                            pd.DataFrame(_seed_rows("iql", wiring, "wiring")))
    iql = next(line for line in lines if line.startswith("| **IQL**"))
    cells = [c.strip() for c in iql.strip("|").split("|")]
    w = stats.ttest_ind(wiring, ours, equal_var=False)
    share = sum(wiring) / 5 - sum(ours) / 5
    assert cells[5].startswith(f"{share:+.4f}") and f"p = {w.pvalue:.3f}" in cells[5]
    assert "tie" not in cells[5]  # URB's wiring moves IQL by +0.6 min, far outside the seeds' spread
    row = paper["tables"][0]["rows"]["iql"]
    m = row["values"]["t_CAV"]
    left = m - sum(wiring) / 5
    assert cells[6].startswith(f"{left:+.4f}") and cells[6].endswith("**tie**")  # inside both spreads
    assert cells[7] == "1/5 [1%, 72%]"  # 3.13 beats its t_pre 3.1585; Clopper-Pearson [0.5%, 71.6%]
    assert any(line.startswith("| **QMIX**") and line.count("not run yet") == 5 for line in lines)


def test_the_sensitivity_variants_take_their_original_rows_from_the_original_entry():
    """tab:sensitivity_kpis compares each variant with its 'Original' rows: ours are the
    sensitivity_original entry's IQL and MAPPO runs (rows_from 'entry:row')."""
    from urb_jax.reporting.paper import _entry_seeds

    data = load_paper_numbers()
    paper = data["entries"]["sensitivity_demand_half"]
    assert paper["rows_from"]["iql_original"] == "sensitivity_original:iql"
    original = pd.DataFrame(_seed_rows("iql", [3.40, 3.42], "original")
                            + _seed_rows("mappo", [3.5], "original"))
    half = pd.DataFrame(_seed_rows("iql", [3.30], "half"))
    res = EntryResults("sensitivity_demand_half", "t", half, 2, 1, 5)
    seeds = _entry_seeds(res, paper, "saint_arnoult", {"sensitivity_original": original})
    assert list(seeds["iql"]["t_CAV_duration"]) == [3.30]  # the variant's own run
    assert list(seeds["iql_original"]["t_CAV_duration"]) == [3.40, 3.42]
    assert list(seeds["mappo_original"]["t_CAV_duration"]) == [3.5]
    assert "mappo" not in seeds  # not run yet in the variant


def test_rows_from_must_name_an_entry(tmp_path):
    data = json.loads(paper_file().read_text())
    data["entries"]["sensitivity_demand_half"]["rows_from"]["iql_original"] = "sensitivity_originl:iql"
    bad = tmp_path / "paper.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match=r"iql_original: 'sensitivity_originl:iql' names no entry"):
        load_paper_numbers(bad)


def test_an_entry_can_take_some_rows_of_another_entrys_tables(tmp_path):
    """scenario1_qmix_config3 is judged against scenario1's St. Arnoult QMIX row and baselines only,
    so the algorithms it does not run are not counted as 'not run yet'."""
    data = load_paper_numbers()
    tables = data["entries"]["scenario1_qmix_config3"]["tables"]
    assert [t["network"] for t in tables] == ["saint_arnoult"]
    assert set(tables[0]["rows"]) == {"qmix", "human", "aon", "random"}
    assert tables[0]["rows"]["qmix"] == data["entries"]["scenario1"]["tables"][0]["rows"]["qmix"]
    raw = json.loads(paper_file().read_text())
    raw["entries"]["scenario1_qmix_config3"]["tables_from"]["rows"] = ["qmix", "qmx"]
    bad = tmp_path / "paper.json"
    bad.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match=r"tables_from\.rows: \['qmx'\] are not rows"):
        load_paper_numbers(bad)


def test_the_human_row_reads_the_group_with_most_seeds_whatever_the_order_runs_were_read_in():
    import pandas as pd

    from urb_jax.reporting.paper import human_key

    five, one = pd.DataFrame({"t_pre": [3.0] * 5}), pd.DataFrame({"t_pre": [3.0]})
    assert human_key({"aon": one, "iql": five, "mappo": five}) == "iql"  # read from the ledger
    assert human_key({"mappo": five, "iql": five, "aon": one}) == "iql"  # read from a results folder
    assert human_key({}) is None
