"""The hybrid trainer: URB's experiment with CAV training split between a calibrated surrogate
(jitted, many envs) and SUMO days that fine-tune the policies and refit the surrogate.

Seeds train together (`trainer.train_group`): the learner state has a leading seed axis, every
jitted piece (`fns.build_fns`) is vmapped over it, and each round's SUMO days of all seeds go to
the executor as one batch. Phases (one results folder per training seed, URB layout):
1. human learning: H SUMO days (`urb_jax.training.human_phase`, t_pre = last 50);
2. mutation (`draw_cavs`), surrogate calibration on the last `calib_human_days` human days plus
   `calib_varied_days` SUMO days of varied joint actions (not experiment days, not in records);
3. rounds (`plan.plan_rounds`): `surrogate_days_per_round` env-days of learner iterations on the
   surrogate (mode hybrid/surrogate), then `sumo_days_per_round` P SUMO days in parallel (mode
   hybrid/sumo) played by the current exploring policies (CAVs act in departure order on the real
   humans' choices), then `sumo_updates` updates on those days, then (hybrid) a refit on
   `refit_days` days drawn from every SUMO day so far; a checkpoint ends each round
   (`urb_jax.training.checkpoints`);
4. test: `test_eps` SUMO days with frozen (greedy) policies.

Budget: `train_days` URB-equivalent training days = surrogate env-days + SUMO training days,
never more: full rounds, then a shorter last round of what is left (`plan.RoundPlan`).
Records hold SUMO days only (column sumo=True); surrogate days are summarised per round in
`rounds.csv`, so every metric and t_train come from SUMO days. Every random choice of round r
flows from fold_in(PRNGKey(seed), r) and the checkpointed state, so `--resume` after a kill
reproduces an uninterrupted run.

Modules: `plan` (config, round sizes, the learner fitted to the budget), `fns` (the jitted
pieces), `trainer` (setup, start/resume, the round's legs, refit, checkpoint, test).
"""
