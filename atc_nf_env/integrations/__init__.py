"""Thin adapters for the multi-agent RL libraries, only where a library cannot take the
environments as they are. Each module imports its library on use; install the library
yourself (the versions tested are in ``examples/requirements-*.txt``).

- ``atc_nf_env.integrations.rllib``: env creators for ``tune.register_env`` (parallel,
  AEC and centralized forms), so that ``PPOConfig().environment("atc_nf_env_parallel",
  env_config={...})`` works on every env runner of a Ray cluster; the centralized form
  (``"atc_nf_env_encounter"``) has a flat action vector for single-agent algorithms.
- ``atc_nf_env.integrations.torchrl``: ``AtcNfBatchedEnv``, B worlds of the native
  vector env as one TorchRL env (one kernel call a step; IPPO/MAPPO in
  ``agents.marl_torchrl`` train on it), and ``make_torchrl_env``, TorchRL's
  ``PettingZooWrapper`` with the two settings this env needs (``use_mask=True``: agents
  leave on arrival; ``done_on_any=False``: the episode goes on until the last has).
- ``atc_nf_env.integrations.benchmarl``: ``AtcNfTask``, a BenchMARL task.
- ``atc_nf_env.integrations.supersuit``: SuperSuit's multi-process vector env for
  Stable-Baselines3, seedable by ``PPO(..., seed=...)``.

``torchrl.envs.GymEnv("atc_nf_env/Encounter-v1")`` and ``GymWrapper(gym.make_vec(...))``
take the centralized env as it is, and PettingZoo's own tests (``max_cycles_test``,
``api_test``, ``parallel_api_test``) take the PettingZoo forms. RLlib's single-agent
algorithms need a flat action vector and an env their remote runners can build: use the
registered ``"atc_nf_env_encounter"`` (``atc_nf_env.envs.wrappers.FlattenActions``).
"""
