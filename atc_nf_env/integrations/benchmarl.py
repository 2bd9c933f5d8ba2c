"""BenchMARL: the encounter as a BenchMARL task (continuous actions, one group
``aircraft``, the global state for centralized critics).

    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig
    from atc_nf_env.integrations.benchmarl import AtcNfTask

    task = AtcNfTask.ENCOUNTER.get_task(config={"scenario": "converging-4", "max_cycles": 24})
    Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(),
               model_config=MlpConfig.get_from_yaml(), critic_model_config=MlpConfig.get_from_yaml(),
               seed=0, config=ExperimentConfig.get_from_yaml()).run()

``config`` holds the environment's keyword arguments (``atc_nf_env.envs``); the env is
``atc_nf_env.integrations.torchrl.make_torchrl_env`` (``use_mask=True``,
``done_on_any=False``).
"""

from __future__ import annotations

import copy
from typing import Any, Callable

from benchmarl.environments.common import Task, TaskClass
from torchrl.data import Composite
from torchrl.envs import EnvBase

from atc_nf_env.envs import EnvConfig
from atc_nf_env.integrations.torchrl import make_torchrl_env


class AtcNfTaskClass(TaskClass):
    """BenchMARL's view of the env: what its algorithms read from the TorchRL specs."""

    def get_env_fun(self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any) -> Callable[[], EnvBase]:
        config = copy.deepcopy(dict(self.config))
        return lambda: make_torchrl_env(return_state=True, seed=seed, device=device, **config)

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return EnvConfig.from_kwargs(dict(self.config), "AtcNfTask").max_decisions

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def _group_keys(self, env: EnvBase, keep: str) -> Composite:
        spec = env.observation_spec.clone()
        for group in self.group_map(env):
            for key in list(spec[group].keys()):
                if key != keep:
                    del spec[group][key]
        if "state" in spec.keys():
            del spec["state"]
        return spec

    def observation_spec(self, env: EnvBase) -> Composite:
        return self._group_keys(env, "observation")

    def info_spec(self, env: EnvBase) -> Composite | None:
        return self._group_keys(env, "info")

    def state_spec(self, env: EnvBase) -> Composite | None:
        return Composite({"state": env.observation_spec["state"].clone()})

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None  # continuous actions: nothing to mask

    @staticmethod
    def env_name() -> str:
        return "atc_nf_env"


class AtcNfTask(Task):
    """The encounter; give the env's arguments with ``get_task(config={...})``."""

    ENCOUNTER = None

    @staticmethod
    def associated_class() -> type[TaskClass]:
        return AtcNfTaskClass


__all__ = ["AtcNfTask", "AtcNfTaskClass"]
