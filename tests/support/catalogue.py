"""The paper's experiment catalogue: its suite files' folder and its entries, in the paper's order,
with the SUMO-only control and URB's wiring beside Scenario 1 (test_catalogue.py's and test_paper.py's)."""

from __future__ import annotations

from pathlib import Path

SUITES = Path(__file__).resolve().parents[2] / "configs" / "suites"
CATALOGUE = ["scenario1", "scenario1_sumo", "urb_wiring", "scenario1_qmix_config3",
             "scenario2", "adjusted_iql_ippo",
             "demo_nangis_selfish_adapt", "demo_nemours_malicious", "demo_gretz_altruistic_adapt",
             "sensitivity_demand_half", "sensitivity_demand_double", "sensitivity_global_obs",
             "sensitivity_original"]
