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

.PHONY: demo test docs test-integrations bench reproduce clean baselines

# A venv with the CPU torch installed first, then the given pip arguments:
# $(call torch_venv,VENV_DIR,PIP_ARGUMENTS)
define torch_venv
	$(PYTHON) -m venv $(1)
	$(1)/bin/pip install --quiet --upgrade pip
	$(1)/bin/pip install --quiet "$(TORCH)"
	$(1)/bin/pip install --quiet $(2)
endef

# The extras in a variable: a comma inside $(call)'s arguments would split them.
TEST_INSTALL := -e ".[test,rl,ray,dataset,docs]"
$(BIN)/atc-nf: pyproject.toml
	$(call torch_venv,$(VENV),$(TEST_INSTALL))
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

# The documentation site (Sphinx, Furo, MyST) into out/docs; any warning fails the build.
docs: $(BIN)/atc-nf
	$(BIN)/python -m sphinx -W --keep-going -q -b html docs out/docs

# The MARL libraries (integration_tests/, examples/train_*.py) in venvs of their own:
# RLlib pins an older gymnasium than the default venv, BenchMARL an older torchrl than
# TorchRL's example uses, AgileRL a pettingzoo of its own. Each example trains a few
# iterations; each venv's tests are bounded by INTEGRATIONS_TIMEOUT_S seconds. The docs'
# code blocks that need RLlib, TorchRL or BenchMARL run in that library's venv.
RLLIB_VENV ?= .venv-rllib
TORCH_VENV ?= .venv-torch
BENCHMARL_VENV ?= .venv-benchmarl
AGILERL_VENV ?= .venv-agilerl
INTEGRATIONS_TIMEOUT_S ?= 1500

$(RLLIB_VENV)/.installed: pyproject.toml examples/requirements-rllib.txt
	$(call torch_venv,$(RLLIB_VENV),-e . -r examples/requirements-rllib.txt)
	touch $@

$(TORCH_VENV)/.installed: pyproject.toml examples/requirements-torch.txt
	$(call torch_venv,$(TORCH_VENV),-e ".[rl]" -r examples/requirements-torch.txt)
	touch $@

$(BENCHMARL_VENV)/.installed: pyproject.toml examples/requirements-benchmarl.txt
	$(call torch_venv,$(BENCHMARL_VENV),-e . -r examples/requirements-benchmarl.txt)
	$(BENCHMARL_VENV)/bin/pip install --quiet --no-deps benchmarl==1.5.2
	touch $@

$(AGILERL_VENV)/.installed: pyproject.toml examples/requirements-agilerl.txt
	$(call torch_venv,$(AGILERL_VENV),-e . -r examples/requirements-agilerl.txt)
	touch $@

test-integrations: $(RLLIB_VENV)/.installed $(TORCH_VENV)/.installed $(BENCHMARL_VENV)/.installed $(AGILERL_VENV)/.installed
	timeout $(INTEGRATIONS_TIMEOUT_S) $(TORCH_VENV)/bin/python -m pytest -q -p no:cacheprovider integration_tests/test_torch_libraries.py integration_tests/test_torchrl_marl.py
	ATC_NF_SNIPPETS_OF=torchrl timeout $(INTEGRATIONS_TIMEOUT_S) $(TORCH_VENV)/bin/python -m pytest -q -p no:cacheprovider \
		tests/test_docs_snippets.py -k 'python_block_runs or library_venv'
	timeout $(INTEGRATIONS_TIMEOUT_S) $(BENCHMARL_VENV)/bin/python -m pytest -q -p no:cacheprovider integration_tests/test_benchmarl.py
	ATC_NF_SNIPPETS_OF=benchmarl timeout $(INTEGRATIONS_TIMEOUT_S) $(BENCHMARL_VENV)/bin/python -m pytest -q -p no:cacheprovider \
		tests/test_docs_snippets.py -k 'python_block_runs or library_venv'
	timeout $(INTEGRATIONS_TIMEOUT_S) $(RLLIB_VENV)/bin/python -m pytest -q -p no:cacheprovider integration_tests/test_rllib.py
	ATC_NF_SNIPPETS_OF=ray.rllib timeout $(INTEGRATIONS_TIMEOUT_S) $(RLLIB_VENV)/bin/python -m pytest -q -p no:cacheprovider \
		tests/test_docs_snippets.py -k 'python_block_runs or library_venv'
	timeout $(INTEGRATIONS_TIMEOUT_S) $(AGILERL_VENV)/bin/python -m pytest -q -p no:cacheprovider integration_tests/test_agilerl.py

bench: $(BIN)/atc-nf
	$(BIN)/python bench/bench_kernel.py --write
	$(BIN)/python bench/bench_compile.py --write
	$(BIN)/python bench/integration_step_study.py --write
	$(BIN)/python bench/substep_watch_study.py --write
	$(BIN)/python bench/integration_convergence_study.py --write
	$(BIN)/python bench/bench_mpc.py --write
	$(BIN)/python bench/bench_envs.py --write
	$(BIN)/python bench/bench_shield.py --write
	$(BIN)/python bench/nf_floor_study.py --shield stream-30,stream-60 --write

# The paper's section IV from fresh runs, into out/reproduction/ (REPRODUCE_ARGS="--runs 1000
# --write" updates the tracked REPRODUCTION.md and docs/figures/ instead).
REPRODUCE_ARGS ?= --runs 1000
reproduce: $(BIN)/atc-nf
	$(BIN)/atc-nf reproduce $(REPRODUCE_ARGS)

# The venvs, out/, and numba's and Python's caches (a stale numba cache can outlive the
# source it was compiled from: numba keys a function on its own file only).
clean:
	rm -rf $(VENV) $(DEMO_VENV) $(RLLIB_VENV) $(TORCH_VENV) $(BENCHMARL_VENV) $(AGILERL_VENV) out
	find . -path ./.git -prune -o \( -name '*.nbi' -o -name '*.nbc' \) -type f -print | xargs rm -f
	find . -path ./.git -prune -o -name __pycache__ -type d -print | xargs rm -rf

# The benchmark's baseline table (docs/baselines.md): SB3 PPO, BC and DAgger (3 seeds each),
# IPPO/MAPPO (TorchRL), the MPC and the NF alone, on the test
# split of converging-4 and random-6, alone and in the safety filter. Resumable (out/baselines).
# In TorchRL's venv, with the rl extra: every row, IPPO/MAPPO included (the table refuses to
# run without them). BASELINES_ARGS=--restart empties out/baselines of another build first.
BASELINES_ARGS ?=
baselines: $(TORCH_VENV)/.installed
	$(TORCH_VENV)/bin/python -m agents.baselines_table --write $(BASELINES_ARGS)
