# Every target builds its own virtual environment, so a fresh machine needs only python3.11.
PYTHON ?= python3.11
VENV ?= .venv
PY := $(VENV)/bin/python
export HF_HUB_OFFLINE := 1
export MUJOCO_GL ?= egl

.PHONY: install lint test test-slow train-local clean quickstart benchmark benchmark-lite benchmark-pixels benchmark-label-free results settings-table

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $@

install: $(VENV)/.installed

lint: install
	$(VENV)/bin/ruff check lerobot_ccdp tests lerobot_policy_ccdp.py
	$(VENV)/bin/ruff format --check lerobot_ccdp tests lerobot_policy_ccdp.py

test: install
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder --durations=0 --durations-min=5

test-slow: install
	$(PY) -m pytest -q -m slow

clean:
	rm -rf $(VENV) outputs .pytest_cache

# README "Train on a local dataset": the base (DP), the recovery rows and the recovery stage (CCDP), in a folder
# of its own per run.
train-local: install
	test -d data/reaching2d || $(PY) -m lerobot_ccdp.benchmark.reaching2d --root data/reaching2d
	run=outputs/train-local/$$(date +%Y%m%d-%H%M%S) && \
	$(VENV)/bin/lerobot-train --policy.type=ccdp --dataset.repo_id=local/reaching2d --dataset.root=data/reaching2d \
		--output_dir=$$run/base --steps=2000 --batch_size=64 --num_workers=0 --policy.push_to_hub=false && \
	$(VENV)/bin/lerobot-ccdp-synthesize --policy.path=$$run/base/checkpoints/last/pretrained_model \
		--dataset.repo_id=local/reaching2d --dataset.root=data/reaching2d --output.root=$$run/recovery_rows && \
	$(VENV)/bin/lerobot-train --policy.path=$$run/base/checkpoints/last/pretrained_model \
		--policy.training_stage=recovery --dataset.repo_id=local/recovery_rows --dataset.root=$$run/recovery_rows \
		--output_dir=$$run/ccdp --steps=1500 --batch_size=64 --num_workers=0 --policy.push_to_hub=false

# JOBS stages at a time, with cores / JOBS torch threads each (pipeline --jobs): the baselines' evaluations beside
# the synthesis and the recovery stage, the recovery's evaluations two at a time (docs/benchmarks.md, Speed).
JOBS ?= 2
# The main job end to end on one task (record, train base, synthesise, train recovery, evaluate CCDP vs DP), in
# a folder of its own per task, so that a second task's report does not replace the first's.
TASK ?= DoorOpening-v0
quickstart: install
	$(PY) -m lerobot_ccdp.benchmark.pipeline --tasks $(TASK) --methods dp ccdp --out outputs/quickstart/$(TASK) \
		--jobs $(JOBS)

# The paper's comparison: the five tasks with contact physics on the Franka Panda, DP / DP* / CCDP and the no-repeat
# oracle; outputs in outputs/benchmark, each task's report in docs/benchmark/<task>.md as soon as the task is done
# (a round takes hours: `make benchmark TASKS="Bartender-v0"` runs the tasks a stopped round has left).
# METHODS="dp dp_star dp_star_matched ccdp ccdp_eps_z" adds the paper's eq. (4) with the eps_z heads, trained from
# the same bases (docs/benchmarks.md); empty: the pipeline's default methods.
TASKS ?= all
METHODS ?=
benchmark: install
	$(PY) -m lerobot_ccdp.benchmark.pipeline --tasks $(TASKS) --out outputs/benchmark --publish-each docs/benchmark \
		--jobs $(JOBS) $(if $(METHODS),--methods $(METHODS))

# The same comparison on the geometric versions of the five tasks (`<Task>-lite-v0`, docs/tasks.md).
benchmark-lite: install
	$(PY) -m lerobot_ccdp.benchmark.pipeline --tasks lite --out outputs/benchmark_lite --publish docs/benchmark_lite_report.md

# The same comparison on rendered cameras (64x64 front camera + robot state) for the two tasks with pixel configs.
benchmark-pixels: install
	$(PY) -m lerobot_ccdp.benchmark.pipeline --tasks DoorOpening-lite-v0 ButtonSearch-lite-v0 --obs-type pixels_agent_pos \
		--out outputs/benchmark_pixels --publish docs/benchmark_pixels_report.md

# The same comparison without labels (z = where an option ends, `final_state`), from each task's
# configs/<task>_label_free/ and datasets_recipes/<task>_label_free.yaml.
benchmark-label-free: install
	$(PY) -m lerobot_ccdp.benchmark.pipeline --label-free --tasks $(TASKS) --out outputs/label_free \
		--publish-each docs/benchmark_label_free --jobs $(JOBS) $(if $(METHODS),--methods $(METHODS))

# docs/results.md and the README's results table, from the per-episode run files the benchmarks publish beside
# each task's report (lerobot_ccdp/benchmark/results.py), one table per run in the order of `--tasks all` (read
# from the pipeline when the recipe runs, after `install`).
ROUND_TASKS = $(shell $(PY) -c "from lerobot_ccdp.benchmark.pipeline import TASK_GROUPS; print(*TASK_GROUPS['all'])")
results: install
	$(PY) -m lerobot_ccdp.benchmark.results --readme README.md \
		--run "With option labels (make benchmark)" $(ROUND_TASKS:%=docs/benchmark/%.json) \
		--run "Without labels (make benchmark-label-free)" $(ROUND_TASKS:%=docs/benchmark_label_free/%.json)

# configs/README.md's table of what each settings folder sets beyond the defaults, written from the files
# (lerobot_ccdp/benchmark/task_settings.py); a test fails when it is stale.
settings-table: install
	$(PY) -m lerobot_ccdp.benchmark.task_settings --write
