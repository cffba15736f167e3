"""configs/paper/urb_paper.json against the paper's LaTeX source itself: every cell of its tables
(`tab:kpis` with stds, `tab:new_imp`, `tab:sensitivity_kpis`, `tab:comp_time`, `tab:hardware`,
`tab:demand`) read off the table rows of urb_paper.tex, and the demand table against the networks'
agents.csv files.

The .tex is not in the repository. It is found at $URB_PAPER_TEX (the file, or the folder holding
urb_paper.tex) or at ../shared/paper/urb_paper.tex next to the repository; without it the tests
are skipped, saying where they looked."""

from __future__ import annotations

import csv
import os
import re
from pathlib import Path

import pytest

from urb_jax.reporting.paper import load_paper_numbers

REPO = Path(__file__).resolve().parents[1]


def _tex_path() -> Path:
    env = os.environ.get("URB_PAPER_TEX")
    path = Path(env) if env else REPO.parent / "shared" / "paper"
    return path / "urb_paper.tex" if path.is_dir() else path


@pytest.fixture(scope="module")
def tex() -> str:
    path = _tex_path()
    if not path.is_file():
        pytest.skip(f"the paper's LaTeX source not found at {path} (set URB_PAPER_TEX to urb_paper.tex or "
                    "its folder, or put it at ../shared/paper/urb_paper.tex)")
    return path.read_text()


def _table(tex: str, label: str) -> str:
    """The table environment holding \\label{label}."""
    at = tex.index(f"\\label{{{label}}}")
    return tex[tex.rindex("\\begin{table}", 0, at):tex.index("\\end{table}", at)]


def _plain(cell: str) -> str:
    """A cell without its LaTeX markup: '\\underline{\\textbf{0.80}} (0.06)' -> '0.80 (0.06)'."""
    cell = re.sub(r"\\(multicolumn|multirow)\{[^}]*\}\{[^}]*\}", "", cell)
    cell = re.sub(r"\\rotatebox\[[^]]*\]\{[^}]*\}\{[^}]*\}", "", cell)
    for _ in range(3):
        cell = re.sub(r"\\(underline|textbf|texttt|text)\{([^{}]*)\}", r"\2", cell)
    cell = cell.replace("$\\sim$", "").replace("\\%", "").replace("$", "").replace("{", "").replace("}", "")
    cell = cell.replace("~", " ")
    return cell.strip()


def _rows(table: str) -> list[list[str]]:
    """The tabular's rows after its header rule, each a list of plain cells."""
    body = table[table.index("\\midrule"):table.index("\\bottomrule")]
    body = re.sub(r"\\(midrule|cmidrule\([a-z]*\)\{[^}]*\})", "", body)
    body = re.sub(r"(?<!\\)%[^\n]*", "", body)  # comments, not \%
    rows = [[_plain(c) for c in r.split("&")] for r in body.split("\\\\")]
    return [r for r in rows if any(r)]


def _number(cell: str) -> tuple[float | None, float | None]:
    """'3.28 (0.004)' -> (3.28, 0.004); '0' -> (0.0, None); 'N/A' -> (None, None)."""
    if cell == "N/A":
        return None, None
    m = re.fullmatch(r"(-?[\d.]+)\s*(?:\(([\d.]+)\))?", cell)
    assert m, f"not a number cell: {cell!r}"
    return float(m[1]), (float(m[2]) if m[2] else None)


NETWORKS = {"St. Arnoult": "saint_arnoult", "Provins": "provins",
            "Ingolstadt": "ingolstadt_custom"}
ALGS = {"IPPO": "ippo", "IQL": "iql", "MAPPO": "mappo", "QMIX": "qmix", "Human": "human", "AON": "aon",
        "Random": "random", "IPPO*": "ippo_star", "IQL*": "iql_star"}


def _by_network(table: str, label: str, columns: list[str]) -> dict[tuple[str, str], dict]:
    """(network, alg) -> {column: (mean, sd)} of a table whose rows are grouped by a rotated network name."""
    names = re.findall(r"\\rotatebox\[[^]]*\]\{[^}]*\}\{([^}]*)\}", table)
    out, network, seen = {}, None, 0
    for raw in table[table.index("\\midrule"):table.index("\\bottomrule")].split("\\\\"):
        if "\\rotatebox" in raw:
            network = NETWORKS[names[seen].replace("~", " ")]
            seen += 1
        row = _rows("\\midrule" + raw + "\\bottomrule")
        if not row:
            continue
        cells = [c for c in row[0] if c]
        alg = ALGS[cells[0]]
        assert len(cells) == len(columns) + 1, (label, network, cells)
        out[(network, alg)] = {c: _number(x) for c, x in zip(columns, cells[1:], strict=True)}
    return out


def _paper_tables(entry: str) -> dict[str, dict]:
    return {t["network"]: t for t in load_paper_numbers()["entries"][entry]["tables"]}


def _check(expected: dict[tuple[str, str], dict], tables: dict[str, dict], where: str) -> int:
    """Every (mean, sd) of `expected` equals the data file's value (and sd); returns the cells checked."""
    checked = 0
    for (network, alg), cells in expected.items():
        row = tables[network]["rows"][alg]
        for col, (mean, sd) in cells.items():
            assert row["values"].get(col) == mean, (where, network, alg, col)
            assert row.get("sd", {}).get(col) == sd, (where, network, alg, col, "sd")
            checked += 1
    return checked


def test_tab_kpis_every_cell_and_its_std(tex):
    table = _table(tex, "tab:kpis")
    cols = ["t_test", "t_CAV", "t_HDV_post", "c_all", "c_HDV", "c_CAV", "delta_V", "delta_L", "WR"]
    cells = _by_network(table, "tab:kpis", cols)
    assert len(cells) == 21
    assert _check(cells, _paper_tables("scenario1"), "tab:kpis") == 21 * 9
    # t_pre, from the caption
    pre = re.search(r"St\. Arnoult: ([\d.]+), Provins: ([\d.]+), Ingolstadt: ([\d.]+)", table)
    assert pre
    for net, value in zip(("saint_arnoult", "provins", "ingolstadt_custom"), pre.groups(), strict=True):
        rows = _paper_tables("scenario1")[net]["rows"].values()
        assert all(r["values"]["t_pre"] == float(value) for r in rows), net
    assert "five seeded runs" in table


def test_tab_new_imp_every_cell(tex):
    cells = _by_network(_table(tex, "tab:new_imp"), "tab:new_imp", ["t_CAV", "c_CAV", "WR"])
    assert len(cells) == 18
    assert _check(cells, _paper_tables("adjusted_iql_ippo"), "tab:new_imp") == 18 * 3


def test_tab_sensitivity_every_cell(tex):
    rows = {r[0]: r[1:] for r in _rows(_table(tex, "tab:sensitivity_kpis"))}
    assert len(rows) == 7
    entry = {"Half demand": "sensitivity_demand_half", "Double demand": "sensitivity_demand_double",
             "Global observations": "sensitivity_global_obs"}
    checked = 0
    for name, cells in rows.items():
        alg, setting = re.fullmatch(r"(IQL|MAPPO) \((.*)\)", name).groups()  # type: ignore[union-attr]
        values = dict(zip(("t_pre", "t_CAV", "delta_pct"), (_number(c)[0] for c in cells), strict=True))
        if setting == "Original":  # the reference row, in every entry that compares with it
            found = [t["rows"][f"{alg.lower()}_original"]["values"] for e in entry.values()
                     for t in _paper_tables(e).values() if f"{alg.lower()}_original" in t["rows"]]
            assert found and all(v == values for v in found), name
        else:
            table = _paper_tables(entry[setting])["saint_arnoult"]
            assert table["rows"][alg.lower()]["values"] == values, name
        checked += 3
    assert checked == 21


def test_tab_comp_time_and_hardware(tex):
    data = load_paper_numbers()["compute"]
    runs = [(r[0], r[1], float(r[2])) for r in _rows(_table(tex, "tab:comp_time"))]
    name = {"St. Arnoult": "saint_arnoult", "Provins": "provins", "Ingolstadt": "ingolstadt_custom"}
    alg = {"QMIX": "qmix", "AON (Baseline)": "aon"}
    assert [(name[n], alg[a], h) for n, a, h in runs] == [
        (r["network"], r["algorithm"], r["hours"]) for r in data["runs"]]
    hardware = dict(_rows(_table(tex, "tab:hardware")))
    assert {k: v for k, v in data["hardware"].items() if k != "source"} == hardware


def test_tab_demand_every_region(tex):
    rows = _rows(_table(tex, "tab:demand"))
    demand = load_paper_numbers()["demand"]["regions"]
    accents = {"\\'E": "É", "\\'e": "é"}
    regions = []
    for region, trips, od in rows:
        for latex, char in accents.items():
            region = region.replace(latex, char)
        regions.append((region, int(trips), int(od)))
    assert regions == [(r["region"], r["trips"], r["od_pairs"]) for r in demand]


def test_the_demand_table_matches_the_networks_agents(real_networks_dir):
    """The check the data file records: each network's agents.csv has the paper's number of trips and
    of distinct (origin, destination) pairs."""
    demand = [r for r in load_paper_numbers()["demand"]["regions"] if r["network"]]
    assert len(demand) == 9
    for r in demand:
        with (real_networks_dir / r["network"] / "agents.csv").open() as f:
            agents = list(csv.DictReader(f))
        assert (len(agents), len({(a["origin"], a["destination"]) for a in agents})) == (
            r["trips"], r["od_pairs"]), r["network"]


def test_the_contradictions_the_page_lists_are_in_the_paper(tex):
    """Each item of the data file's `contradictions`, checked on the transcribed numbers (themselves
    checked against the .tex above) and on the captions it quotes."""
    data = load_paper_numbers()
    assert len(data["contradictions"]) == 4
    kpis = {t["network"]: t["rows"] for t in data["entries"]["scenario1"]["tables"]}
    readme = {t["network"]: t["readme"]["values"] for t in data["entries"]["scenario1"]["tables"]}
    # tab:new_imp's IQL/IPPO rows are tab:kpis' (6,000 days), its caption says 2,000
    for t in data["entries"]["adjusted_iql_ippo"]["tables"]:
        for alg in ("iql", "ippo"):
            row, old = t["rows"][alg], kpis[t["network"]][alg]
            for col in ("t_CAV", "c_CAV"):
                assert (row["values"][col], row["sd"][col]) == (old["values"][col], old["sd"][col])
    assert "CAV learning (2~000 episodes)" in _table(tex, "tab:new_imp")
    assert "200, 6~000, and 100 episodes" in tex  # fig:travel_times_1: Scenario 1's training length
    # tab:sensitivity_kpis' IQL (Original) is tab:kpis' IQL; its caption says 1,200 episodes
    sens = load_paper_numbers()["entries"]["sensitivity_demand_half"]["tables"][0]["rows"]
    assert sens["iql_original"]["values"]["t_CAV"] == kpis["saint_arnoult"]["iql"]["values"]["t_CAV"] == 3.53
    mappo = (kpis["saint_arnoult"]["mappo"]["values"]["t_CAV"], readme["saint_arnoult"]["mappo"]["t_CAV"])
    assert sens["mappo_original"]["values"]["t_CAV"] not in mappo
    assert "after 1~200 training episodes" in _table(tex, "tab:sensitivity_kpis")
    # c_all outside [c_HDV, c_CAV]: AON on Ingolstadt only; c_all is defined as the mean over all agents
    outside = [(n, a) for n, rows in kpis.items() for a, r in rows.items()
               if {"c_all", "c_HDV", "c_CAV"} <= set(r["values"])
               and not min(r["values"]["c_HDV"], r["values"]["c_CAV"]) <= r["values"]["c_all"]
               <= max(r["values"]["c_HDV"], r["values"]["c_CAV"])]
    assert outside == [("ingolstadt_custom", "aon")]
    assert "/ (|\\mathcal{N}|\\cdot|\\mathcal{S}_\\text{train}|)" in tex
    # humans 'disadvantaged', but Ingolstadt IPPO and MAPPO t_HDV = t_pre
    equal = [a for a, r in kpis["ingolstadt_custom"].items()
             if r["values"].get("t_HDV_post") == 4.21 and a != "human"]
    assert equal == ["ippo", "mappo"] and "human agents" in _table(tex, "tab:kpis")
    # no VDN row in Scenario 1 (the demonstrative experiments are VDN's only appearance)
    assert "VDN" not in _table(tex, "tab:kpis") and all("vdn" not in r for r in kpis.values())


def test_the_travel_time_figures_window_is_the_papers(tex):
    """Each entry's figure names a figure of the paper and smooths by the moving average its
    caption states (150 episodes in both)."""
    figures = {e: v["figure"] for e, v in load_paper_numbers()["entries"].items() if "figure" in v}
    assert set(figures) == {"scenario1", "scenario1_sumo", "scenario2"}
    for entry, spec in figures.items():
        start = tex.index(f"\\label{{{spec['source']}}}")
        caption = tex[tex.rindex("\\caption{", 0, start):start]
        window = re.search(r"moving average of (\d+)", " ".join(caption.split()))
        assert window and int(window[1]) == spec["window"], entry
