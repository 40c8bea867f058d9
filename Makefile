# Two commands do everything on a machine that has python3 and pip:
#   make demo   create .venv, install, reproduce the papers with the scripted baselines into results/
#   make test   the whole test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

# one BLAS/torch thread per process: with two, PPO ran 45x slower on these 2-core machines
export OMP_NUM_THREADS := 1
export MKL_NUM_THREADS := 1
export MPLBACKEND := Agg

EXTRAS := train,dev,bench,fast

.PHONY: demo test install bench docs learn lint format lock clean

# constraints.txt pins every package to the versions CI tested, so a new machine gets those
$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[$(EXTRAS)]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/mrcomm reproduce --all --quick --out results

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q

bench: $(STAMP)
	$(BIN)/mrcomm bench

docs: $(STAMP)
	$(BIN)/mrcomm docs

# learned policies against every baseline at equal bits: trains 3 seeds per cost value and env (about an hour
# on two cores), then regenerates docs/learning.md; reruns skip the runs already done
learn: $(STAMP)
	$(BIN)/mrcomm reproduce-learning --workers 2 --out results/learning

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

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
	rm -rf $(VENV) .lock-venv results .pytest_cache .hypothesis
