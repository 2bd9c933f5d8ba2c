"""Thin adapters for the multi-agent RL libraries, only where a library cannot take the
environments as they are. Each module imports its library on use; install the library
yourself (the versions tested are in ``examples/requirements-*.txt``).

- ``atc_nf_env.integrations.rllib``: env creators for ``tune.register_env`` (parallel and
  AEC forms), so that ``PPOConfig().environment("atc_nf_env_parallel", env_config={...})``
  works on every env runner of a Ray cluster.
- ``atc_nf_env.integrations.torchrl``: ``make_torchrl_env``, TorchRL's
  ``PettingZooWrapper`` with the two settings this env needs (``use_mask=True``: agents
  leave on arrival; ``done_on_any=False``: the episode goes on until the last has).
- ``atc_nf_env.integrations.benchmarl``: ``AtcNfTask``, a BenchMARL task.
- ``atc_nf_env.integrations.supersuit``: SuperSuit's multi-process vector env for
  Stable-Baselines3, seedable by ``PPO(..., seed=...)``.

The centralized env needs no adapter: ``torchrl.envs.GymEnv("atc_nf_env/Encounter-v0")``,
``GymWrapper(gym.make_vec(...))`` and RLlib's single-agent configs take it as it is, and so
do PettingZoo's own tests (``max_cycles_test``, ``api_test``, ``parallel_api_test``).
"""
