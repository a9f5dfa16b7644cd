# fiper-ros: every command does the set-up it needs first (idempotent, seconds when nothing changed).
SHELL := /bin/bash
RUN := source ./env.sh &&

.PHONY: help setup test lint mutants demo study bench-core bench-eval bench-nodes bench-policy bench-soak bench-scale lock clean distclean

help:
	@echo "make demo        the main job: sim bridge, policy and FIPER nodes live, 2 rollouts (runs/demo/)"
	@echo "make study       the FIPER-vs-baselines study on sim rollouts (long; docs/results.md)"
	@echo "make test        set up the workspace if needed, then run the whole test suite"
	@echo "make lint        ruff over fiper_ros, sim_bridge, test and tools (ruff.toml; make test checks it too)"
	@echo "make mutants     mutation testing of core/ and runtime/ (resumable; FILES=core/fusion.py for one file)"
	@echo "make setup       venv with pinned wheels, Debian packages, colcon build (idempotent)"
	@echo "make bench-core  latency of the FIPER core (ACE, RND-OE, fusion)"
	@echo "make bench-eval  speed of the evaluation engine (scores, full sweep) on synthetic data"
	@echo "make bench-nodes start-up, memory, end-to-end latency and throughput of the node suite over DDS"
	@echo "make bench-policy cost of a policy step (embedding, B sampled chunks) of each shipped policy"
	@echo "make bench-scale collection as Ray tasks: time per episode, Ray overhead, 2 workers vs 1 (docs/scale.md)"
	@echo "make bench-soak  an hour of the demo's node set: memory, alarm latency per 5 min (MINUTES=10: per minute)"
	@echo "make lock        regenerate requirements.lock from requirements.in"
	@echo "make clean       remove colcon build/install/log; make distclean also removes the venv"

setup:
	@bash tools/setup.sh

test: setup
	@bash tools/run_tests.sh

lint: setup
	@$(RUN) ruff check fiper_ros sim_bridge test tools

# Not part of make test: minutes per file (docs/testing.md, "Mutation testing"). JOBS: mutants at once.
mutants: setup
	@$(RUN) nice -n 10 python tools/mutants.py $(if $(JOBS),--jobs $(JOBS)) $(FILES)

demo: setup
	@$(RUN) fiper demo

study: setup
	@bash tools/study.sh

bench-core: setup
	@$(RUN) python -m fiper_ros.bench.core_bench

bench-eval: setup
	@$(RUN) python -m fiper_ros.bench.eval_bench

bench-nodes: setup
	@$(RUN) python -m fiper_ros.bench.nodes_bench

bench-policy: setup
	@$(RUN) python -m fiper_ros.bench.policy_bench

bench-scale: setup
	@$(RUN) python -m fiper_ros.bench.scale_bench

bench-soak: setup
	@$(RUN) python -m fiper_ros.bench.soak_bench --minutes $(or $(MINUTES),60)

lock: setup
	@$(RUN) pip install --quiet -r requirements.in && python tools/lock.py > requirements.lock
	@echo "requirements.lock regenerated"

clean:
	rm -rf build install log

distclean: clean
	rm -rf .venv
