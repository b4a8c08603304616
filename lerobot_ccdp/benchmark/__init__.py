"""The benchmark: the pipeline, paired statistics, targets, stamps and lock, the watch GIF and the 2-D
tasks, and the measuring tools, each `python -m lerobot_ccdp.benchmark.<tool> --help`:

- `tune_methods`: a recovery method's settings on the development seeds; `pool_pairs` pools such comparisons
  over trainings; `trace_failures`: why a method's episodes are lost; `trainings`: a round's table over
  several trainings of every task.
- `policy_cost` / `camera_cost`: planning latency and training step against LeRobot's diffusion policy
  (state, camera); `synthesis_cost`: synthesis and training times, and the paper's Fig. 2 on the 2-D task.
- `preference_family`: recovery and demonstrated preferences on the seeded 2-D family (issue 17);
  `segment_agreement`: label-free option ends against the labelled ones; `task_stats`: simulation speed,
  recording time and the no-repeat oracle per task.
- `task_settings`: what each settings folder under configs/ sets beyond the defaults, the table in
  configs/README.md (`--write`, `--check`).

These were scripts under `benchmarks/` until 0032ef5; that commit also holds the two finished one-offs left
out here (`bench_failure_feature.py`, `bench_import.py`), whose figures docs/design_choices.md keeps.
"""
