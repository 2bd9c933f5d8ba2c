# Two commands do all the set-up on a fresh machine:
#   make demo   # the MCMC-MPC flying the paper's 4-aircraft encounter under wind
#   make test   # the test suite
# The demo gets a light venv of its own (numpy, numba, matplotlib, gymnasium, pettingzoo);
# the tests, benchmarks and agents get the full one (torch, Stable-Baselines3, Ray, ...).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
DEMO_VENV ?= .venv-demo
DEMO_BIN := $(DEMO_VENV)/bin
# The torch that `make test` installs first: a CPU build. pyproject.toml asks only for
# torch>=2.3, and a bare requirement would pull a multi-GB CUDA build.
TORCH ?= torch==2.13.0

.PHONY: demo test bench reproduce clean

$(BIN)/atc-nf: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet "$(TORCH)"
	$(BIN)/pip install --quiet -e ".[test,rl,ray]"
	touch $@

# Quick: no pip inside the venv (the host's pip installs into it; `.venv-demo/bin/python -m
# ensurepip` adds one), no byte-compiling at install time. Without a host pip, the slow way.
$(DEMO_BIN)/atc-nf: pyproject.toml
	$(PYTHON) -m venv --without-pip $(DEMO_VENV)
	$(PYTHON) -m pip --python $(DEMO_BIN)/python install --quiet --no-compile -e . \
		|| { $(DEMO_BIN)/python -m ensurepip && $(DEMO_BIN)/python -m pip install --quiet --no-compile -e . ; }
	touch $@

demo: $(DEMO_BIN)/atc-nf
	mkdir -p out
	$(DEMO_BIN)/atc-nf fly --policy mpc --scenario converging-4 --wind-sigma 5.17 --seed 0 \
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
	rm -rf $(VENV) $(DEMO_VENV) out
