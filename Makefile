# Two commands do all the set-up on a fresh machine:
#   make demo   # the MCMC-MPC flying the paper's 4-aircraft encounter under wind
#   make test   # the test suite
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test bench reproduce clean

$(BIN)/atc-nf: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[test,rl,ray]"
	touch $@

demo: $(BIN)/atc-nf
	$(BIN)/atc-nf fly --policy mpc --scenario converging-4 --wind-sigma 5.17 --seed 0 \
		--summary-json out/summary.json --plots out/figs

test: $(BIN)/atc-nf
	$(BIN)/python -m pytest -q

bench: $(BIN)/atc-nf
	$(BIN)/python bench/bench_kernel.py --write
	$(BIN)/python bench/integration_step_study.py --write
	$(BIN)/python bench/bench_mpc.py --write
	$(BIN)/python bench/bench_envs.py --write

reproduce: $(BIN)/atc-nf
	$(BIN)/atc-nf reproduce --runs 1000

clean:
	rm -rf $(VENV) out
