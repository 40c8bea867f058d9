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

.PHONY: demo test install bench docs lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e ".[train,dev,bench,fast]"
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

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) results .pytest_cache .hypothesis
