# Two commands do everything on a machine that has python3 and pip:
#   make demo   create .venv, install, reproduce the papers with the scripted baselines into results/
#   make test   the whole test suite
# and, each in its own venv, the MARL framework integrations: make test-torchrl | test-rllib | test-benchmarl,
# and the sweep runner on a real local Ray cluster: make test-ray
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

# one BLAS/torch thread per process: with two, PPO ran 45x slower on these 2-core machines
export OMP_NUM_THREADS := 1
export MKL_NUM_THREADS := 1
export MPLBACKEND := Agg

EXTRAS := train,dev,bench

.PHONY: demo test fuzz docs-site docs-serve test-wheel install bench bench-benchmarl benchmark benchmark-page docs learn sweep lint format lock clean test-torchrl test-rllib test-benchmarl \
	test-ray

# constraints.txt pins every package to the versions CI tested, so a new machine gets those
$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[$(EXTRAS)]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/mrcomm reproduce --all --quick --out results

# a worker that crashes fails the run at once, naming its test (--max-worker-restart=0), rather than hang it;
# each test process caps its own memory and every test its time (tests/conftest.py, pyproject.toml)
test: $(STAMP)
	$(BIN)/python -m pytest -n 2 --dist loadgroup --max-worker-restart=0 -q

# wide random exploration, not in CI: 1,000 fresh Hypothesis examples per env of the conformance fuzz
# (tests/core/test_conformance.py, profile `fuzz` in tests/conftest.py); each env's count of examples that ran, were
# over the memory budget or were refused is printed. The seed is printed first; replay a run with
# `make fuzz FUZZ_SEED=<seed>`. About two minutes on one core.
FUZZ_SEED ?= $(shell od -An -N4 -tu4 /dev/urandom | tr -d ' ')
fuzz: $(STAMP)
	@echo "make fuzz: hypothesis seed $(FUZZ_SEED) (replay with: make fuzz FUZZ_SEED=$(FUZZ_SEED))"
	HYPOTHESIS_PROFILE=fuzz $(BIN)/python -m pytest tests/core/test_conformance.py -k test_random_valid_configurations_run \
	  -q -s -p no:cacheprovider --timeout 7200 --hypothesis-seed=$(FUZZ_SEED)

# The MARL framework integrations, each in its own venv (.venv-torchrl, .venv-rllib, .venv-benchmarl) because
# their pins clash (ray: gymnasium 1.2.2; benchmarl: torchrl < 0.12). torch goes in first, pinned like the
# train extra, so no framework's looser torch requirement resolves to another (CUDA) build.
TORCH := torch==2.13.0
comma := ,

.venv-%/.installed: pyproject.toml
	test -x .venv-$*/bin/python || $(PYTHON) -m venv .venv-$*
	$(if $(NO_TORCH_$*),,.venv-$*/bin/python -m pip install --quiet "$(TORCH)")
	.venv-$*/bin/python -m pip install --quiet -e ".[$(or $(VENV_EXTRAS_$*),$*)]" "pytest>=8"
	touch $@

# .venv-ray (sweeps on Ray, not RLlib) runs scripted reproductions: no torch, and the dev extra for the test helpers
NO_TORCH_ray := yes
VENV_EXTRAS_ray := ray,dev

# keep the stamp: make would otherwise delete it as an intermediate file and reinstall next time
.PRECIOUS: .venv-%/.installed

# no per-process memory cap here (tests/conftest.py): Ray's raylets map an object store sized from the machine's memory
test-torchrl test-rllib test-benchmarl test-ray: test-%: .venv-%/.installed
	MRCOMM_TEST_MEMORY_GIB=0 .venv-$*/bin/python -m pytest tests/integrations/test_$*.py -q -p no:cacheprovider

# the docs site, strict (a broken link or a missing reference fails it), into site/; the reproductions it shows
# come from results/, which `make demo` writes (a second demo reuses its cached tasks)
.venv-docs/.installed: pyproject.toml constraints.txt constraints-docs.txt
	test -x .venv-docs/bin/python || $(PYTHON) -m venv .venv-docs
	.venv-docs/bin/python -m pip install --quiet -c constraints.txt -c constraints-docs.txt -e ".[docs]"
	touch $@

docs-site: demo .venv-docs/.installed
	NO_MKDOCS_2_WARNING=1 .venv-docs/bin/mkdocs build --strict

docs-serve: demo .venv-docs/.installed
	NO_MKDOCS_2_WARNING=1 .venv-docs/bin/mkdocs serve

# the package as a user installs it: wheel and sdist built and accepted by `twine check`; the wheel installed with
# the train extra in a fresh venv beside PyPI's unrelated `agents` package (its TensorFlow requirements left out:
# nothing imports it), then run from folders with their own agents/ and baselines/ (tests/integrations/test_wheel.py)
WHEEL_VENV := .venv-wheel
test-wheel: $(STAMP)
	rm -rf dist $(WHEEL_VENV)
	$(BIN)/python -m build --outdir dist .
	$(BIN)/twine check --strict dist/*
	$(PYTHON) -m venv $(WHEEL_VENV)
	$(WHEEL_VENV)/bin/python -m pip install --quiet -c constraints.txt "$(TORCH)"
	$(WHEEL_VENV)/bin/python -m pip install --quiet -c constraints.txt "$$(ls dist/*.whl)[train]" pytest hypothesis \
	  pytest-timeout
	$(WHEEL_VENV)/bin/python -m pip install --quiet --no-deps agents==1.4.0
	cd dist && ../$(WHEEL_VENV)/bin/pytest ../tests/integrations/test_wheel.py -q -p no:cacheprovider

bench: $(STAMP)
	$(BIN)/mrcomm bench

# BenchMARL's collection on every task (docs/integrations.md): the batched env beside the older one-wrapper-per-copy
# SerialEnv path and beside an env that costs nothing, on one torch thread; into results/bench-benchmarl.json
bench-benchmarl: .venv-benchmarl/.installed
	OMP_NUM_THREADS=1 .venv-benchmarl/bin/python -m mrcomm_env.experiments.benchmarl_bench

# BenchMARL's reference results (docs/benchmark.md): IPPO, MAPPO and IQL, 3 seeds, 1,000,000 frames a run, into
# docs/benchmark/runs/ in .venv-benchmarl; runs only what has no record yet, so a killed or stopped benchmark
# resumes where it was (an IPPO or MAPPO run cut short goes on from its newest checkpoint, an IQL run starts again).
# The plan's cost per run: docs/benchmark.md.
# BENCHMARK_ARGS passes more, e.g. BENCHMARK_ARGS="--tasks MAPSYNC --jobs 2". Keep MULTIHOP at one job on 23 GB:
# its IPPO run peaked at 14 GB (measured with /usr/bin/time, 36 robots).
benchmark: .venv-benchmarl/.installed
	OMP_NUM_THREADS=1 .venv-benchmarl/bin/python -m mrcomm_env.experiments.benchmarl_reference run $(BENCHMARK_ARGS)

# docs/benchmark.md, its figures and docs/benchmark/marl-eval.json from the runs' committed files
benchmark-page: .venv-benchmarl/.installed
	MPLBACKEND=Agg .venv-benchmarl/bin/python -m mrcomm_env.experiments.benchmarl_reference page

docs: $(STAMP)
	$(BIN)/mrcomm docs

# learned policies against every baseline at equal bits: trains 5 seeds per cost value and env, from random weights or,
# where the section names `init_from` (MultiHop, RendezvousMapping), from a clone of that rule (about 4 hours on two
# cores: MultiHop 165 minutes for its 5 MAPPO runs, RendezvousMapping 31 for its 15 runs, ChannelAssociation 22,
# AsyncCL 13, MapSync 12), then
# regenerates docs/learning.md with its curves (add --export-pretrained to ship the best runs); reruns skip the
# runs already done
learn: $(STAMP)
	$(BIN)/mrcomm reproduce-learning --workers 2 --out results/learning

# the recorded hyperparameter sweeps that chose agents/configs/<Name>-v0.json (a small grid around rl-zoo3's PPO
# defaults, 2 seeds, scored on held-out episodes); each lands in docs/learning/sweep-<Name>-v0.{csv,json}, which
# docs/learning.md shows. About two hours on two cores; reruns skip the finished runs.
SWEEPS := results/sweeps
define sweep
	$(BIN)/mrcomm train $(1) --seeds 0,1 --out $(SWEEPS)/$(1) --workers 2 --quiet $(2)
	cp $(SWEEPS)/$(1)/summary.csv docs/learning/sweep-$(1).csv
	cp $(SWEEPS)/$(1)/sweep.json docs/learning/sweep-$(1).json
endef

sweep: $(STAMP)
	$(call sweep,ChannelAssociation-v0,--grid learning_rate=0.0003$(comma)0.001 --grid ent_coef=0.0$(comma)0.01 --param emission_cost=0.1)
	$(call sweep,MapSync-v0,--grid learning_rate=0.0002$(comma)0.0005 --grid ent_coef=0.0$(comma)0.01 --param lam=0.01)
	$(call sweep,AsyncCL-v0,--grid learning_rate=0.0002$(comma)0.0005 --grid ent_coef=0.0$(comma)0.005 --param lam=0.1)
	$(call sweep,RendezvousMapping-v0,--algo maskable_ppo --grid learning_rate=0.0002$(comma)0.0005 --grid ent_coef=0.0$(comma)0.01 --param d_comms=1000.0)
	$(call sweep,MultiHop-v0,--timesteps 100000 --grid learning_rate=0.0003$(comma)0.001 --grid ent_coef=0.0$(comma)0.01 --param lam=0.0)
	$(BIN)/mrcomm reproduce-learning --docs-only

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python .ci/typecheck.py

format: $(STAMP)
	$(BIN)/ruff format .

# upgrade on purpose: resolve pyproject.toml afresh in a throwaway venv and record what it chose
lock:
	rm -rf .lock-venv && $(PYTHON) -m venv .lock-venv
	.lock-venv/bin/python -m pip install --quiet -e ".[$(EXTRAS)]"
	{ sed -n '1,2p' constraints.txt; .lock-venv/bin/python -m pip freeze --exclude-editable \
	  | grep -v '^mrcomm-env' | sed 's/+cpu$$//'; } > constraints.txt.new
	mv constraints.txt.new constraints.txt && rm -rf .lock-venv

clean:
	rm -rf $(VENV) .venv-torchrl .venv-rllib .venv-benchmarl .venv-ray .venv-docs .venv-wheel .lock-venv results site dist .pytest_cache .hypothesis
