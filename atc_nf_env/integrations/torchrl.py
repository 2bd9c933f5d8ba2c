"""TorchRL: a batched env over the native vector env, and TorchRL's PettingZoo wrapper
with the settings it needs.

    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv, make_torchrl_env
    env = AtcNfBatchedEnv(32, seed=0, scenario="converging-4")   # 32 worlds, one kernel call a step
    rollout = env.rollout(40, break_when_any_done=False)        # group "aircraft", global "state"

    env = make_torchrl_env(scenario="converging-4")             # PettingZooWrapper, one world
    rollout = env.rollout(40)          # group "aircraft": observation, mask, info, ...

``AtcNfBatchedEnv`` (a ``torchrl.envs.EnvBase``, TorchRL 0.14's conventions) steps B
worlds of ``atc_nf_env.envs.vector.BatchWorlds`` together, 45-90 times the frames per
second of ``PettingZooWrapper`` on two cores (``bench/bench_torchrl_env.py``); see its
docstring for the keys. With ``PettingZooWrapper``, aircraft leave the episode when they
arrive, so TorchRL needs ``use_mask=True`` (the group's ``mask`` says which are still
flying), and ``done_on_any=False`` (its default for parallel envs resets the whole
encounter as soon as the first aircraft arrives).
The centralized env needs nothing: ``torchrl.envs.GymEnv("atc_nf_env/Encounter-v1")``.
torchrl is imported on use.

Traffic streams (``scenario="stream-R"``) are refused by both, at construction, with a
ValueError: their agents join and leave during an episode, which neither TorchRL's
PettingZoo wrapper (it reads every possible agent's info at each reset) nor the batched
encounter worlds take. A stream's Gymnasium env has fixed slots with a mask and goes
through ``torchrl.envs.GymEnv("atc_nf_env/Encounter-v1", scenario="stream-60")``.
"""

from __future__ import annotations

from typing import Any


def refuse_streams(scenario: Any, where: str) -> None:
    """ValueError if ``scenario`` is a traffic stream, saying what to use instead."""
    from atc_nf_env.envs.streams import is_stream

    if is_stream(scenario):
        raise ValueError(
            f"{where}: scenario = {scenario!r} is a traffic stream, whose agents join and leave; the TorchRL "
            "integrations (AtcNfBatchedEnv, make_torchrl_env) fly encounters only. For a stream use "
            f"torchrl.envs.GymEnv(\"atc_nf_env/Encounter-v1\", scenario={scenario!r}) (fixed slots with a mask) "
            "or atc_nf_env.parallel_env directly"
        )


def make_torchrl_env(
    *, parallel: bool = True, return_state: bool = False, seed: int | None = None, device: Any = None, **kwargs: Any
) -> Any:
    """``torchrl.envs.PettingZooWrapper`` over ``atc_nf_env.parallel_env(**kwargs)``
    (or the AEC ``atc_nf_env.env`` with ``parallel=False``), with ``use_mask=True`` and
    ``done_on_any=False``. ``return_state`` adds the global state (``state()``) as
    ``"state"`` for centralized critics (MAPPO); ``seed`` seeds the first reset.

    Raises:
        ValueError: for a traffic stream (see the module docstring), before torchrl is
            imported; for any bad keyword argument, as the env does.
    """
    refuse_streams(kwargs.get("scenario"), "make_torchrl_env")
    from torchrl.envs import PettingZooWrapper

    from atc_nf_env.envs.parallel import env, parallel_env

    base = parallel_env(**kwargs) if parallel else env(**kwargs)
    extra = {} if device is None else {"device": device}
    return PettingZooWrapper(
        base, use_mask=True, done_on_any=False, return_state=return_state, seed=seed, **extra
    )


# --------------------------------------------------------------------------- batched env

#: The group holding every aircraft slot's entries.
GROUP = "aircraft"


def _torchrl_env_base() -> type:
    """``torchrl.envs.EnvBase``, imported on first use (torchrl is not a dependency)."""
    try:
        from torchrl.envs import EnvBase
    except ImportError as error:  # pragma: no cover - depends on the install
        raise ImportError(
            "AtcNfBatchedEnv needs torchrl and tensordict: pip install -r examples/requirements-torch.txt"
        ) from error
    return EnvBase


_CLASSES: dict[str, type] = {}


def _batched_env_class() -> type:
    if "batched" in _CLASSES:
        return _CLASSES["batched"]
    EnvBase = _torchrl_env_base()
    import numpy as np
    import torch
    from tensordict import TensorDict, TensorDictBase
    from torchrl.data import Bounded, Categorical, Composite, Unbounded

    from atc_nf_env.envs import EnvConfig
    from atc_nf_env.envs.centralized import validate_step_actions
    from atc_nf_env.envs.vector import BatchWorlds
    from atc_nf_env.scenarios import check_seed

    class AtcNfBatchedEnv(EnvBase):
        """B worlds of the encounter as one TorchRL env, stepped in one kernel call.

        The worlds are the native vector env's (``atc_nf_env.envs.vector.BatchWorlds``):
        world b with episode seed s flies exactly as ``parallel_env(...).reset(seed=s)``
        does (same layout, hidden wind, observations and rewards). TorchRL's conventions
        are those of torchrl 0.14 (``EnvBase`` with ``batch_size=[B]``, a nested group of
        agents, partial resets through a ``"_reset"`` mask that the collectors and
        ``step_and_maybe_reset`` pass for the worlds that ended).

        Keys (shapes for B worlds of M aircraft slots, D the ego observation's size):

        - ``("aircraft", "observation")`` (B, M, D) float32: each aircraft's ego
          observation, as the PettingZoo env gives it; zeros for an aircraft that has
          arrived or left and for padding slots (as SuperSuit's black death does).
        - ``("aircraft", "mask")`` (B, M) bool: the aircraft is still flying.
        - ``("aircraft", "action")`` (B, M, 2) in [-1, 1]: distance and angle of the
          waypoint (the envs' ``ActionMapping``); values outside are clipped, NaN or inf
          raise ValueError. Actions of aircraft no longer flying are ignored.
        - ``("aircraft", "reward")`` (B, M, 1) float32: each aircraft's reward of the
          period (``atc_nf_env.envs.rewards``), 0 once it stopped flying.
        - ``("aircraft", "los_count")`` (B, M) int64 and ``("aircraft",
          "envelope_violation")`` (B, M) bool: the period's losses of separation and
          whether any integration step left [366, 540] kt (what a run's safety is judged on).
        - ``"state"`` (B, S) float32: the global state (``parallel_env().state()``), for
          centralized critics.
        - ``"episode_seed"`` (B,) int64: each world's episode seed.
        - ``"done"``, ``"terminated"``, ``"truncated"`` (B, 1) bool per world: terminated
          when no aircraft is flying any more, truncated at the time limit.

        Args:
            num_envs: B, the number of worlds.
            seed: seeds the first reset (world b gets episode seed ``seed + b``, as the
                vector env does); later resets of a world draw their seeds from that
                world's generator, so one seed fixes every episode. ``set_seed`` does the
                same for the next reset.
            episode_seeds: instead of ``seed``, an iterator of episode seeds: every reset
                takes the next one for each world it resets, in world order (e.g.
                ``itertools.count(first)`` keeps every episode inside a seed range, such
                as a benchmark split's).
            device: torch device of the tensors (the kernel runs on the CPU).
            **kwargs: the environments' keyword arguments (``atc_nf_env.envs``:
                ``scenario``, ``wind_sigma``, ``max_aircraft``, ``n_neighbours``, ...);
                ``render_mode`` must be None. A traffic stream is refused with a
                ValueError (it has no fixed agents; see the module docstring for what
                takes one).
        """

        def __init__(self, num_envs: int = 8, *, seed: int | None = None, episode_seeds: Any = None,
                     device: Any = "cpu", **kwargs: Any) -> None:
            if seed is not None and episode_seeds is not None:
                raise ValueError("AtcNfBatchedEnv: give seed or episode_seeds, not both")
            if episode_seeds is not None and not hasattr(episode_seeds, "__next__"):
                raise ValueError(f"AtcNfBatchedEnv: episode_seeds = {episode_seeds!r}: must be an iterator of ints "
                                 "(e.g. itertools.count(first) or iter(list_of_seeds))")
            cfg = EnvConfig.from_kwargs(kwargs, "AtcNfBatchedEnv")
            refuse_streams(cfg.scenario, "AtcNfBatchedEnv")
            if cfg.render_mode is not None:
                raise ValueError(f"AtcNfBatchedEnv: render_mode = {cfg.render_mode!r}: allowed: None")
            worlds = BatchWorlds(cfg, num_envs, "AtcNfBatchedEnv")
            super().__init__(device=device, batch_size=torch.Size([worlds.num_envs]))
            self.cfg = cfg
            self.worlds = worlds
            self.num_envs = worlds.num_envs
            self.n_slots = worlds.n_slots
            self._pending_seed: int | None = None
            self._episode_seeds = episode_seeds
            #: Episodes begun so far (world resets), over all worlds.
            self.episodes_started = 0
            b, m = self.num_envs, self.n_slots
            obs_space = worlds.obs_spec.space()
            state_space = worlds.obs_spec.state_space(m)
            self.observation_dim = int(obs_space.shape[0])
            self.state_dim = int(state_space.shape[0])

            def box(space: Any, shape: tuple[int, ...]) -> Any:
                low = torch.as_tensor(np.broadcast_to(space.low, shape).copy(), dtype=torch.float32)
                high = torch.as_tensor(np.broadcast_to(space.high, shape).copy(), dtype=torch.float32)
                return Bounded(low=low, high=high, shape=shape, dtype=torch.float32, device=self.device)

            flag = lambda shape: Categorical(n=2, shape=shape, dtype=torch.bool, device=self.device)  # noqa: E731
            self.observation_spec = Composite(
                {
                    GROUP: Composite(
                        {
                            "observation": box(obs_space, (b, m, self.observation_dim)),
                            "mask": flag((b, m)),
                            "los_count": Unbounded(shape=(b, m), dtype=torch.int64, device=self.device),
                            "envelope_violation": flag((b, m)),
                        },
                        shape=(b, m),
                    ),
                    "state": box(state_space, (b, self.state_dim)),
                    "episode_seed": Unbounded(shape=(b,), dtype=torch.int64, device=self.device),
                },
                shape=(b,),
            )
            self.action_spec = Composite(
                {GROUP: Composite({"action": Bounded(low=-1.0, high=1.0, shape=(b, m, 2), dtype=torch.float32,
                                                     device=self.device)}, shape=(b, m))},
                shape=(b,),
            )
            self.reward_spec = Composite(
                {GROUP: Composite({"reward": Unbounded(shape=(b, m, 1), dtype=torch.float32, device=self.device)},
                                  shape=(b, m))},
                shape=(b,),
            )
            self.done_spec = Composite(
                {key: flag((b, 1)) for key in ("done", "terminated", "truncated")}, shape=(b,)
            )
            if seed is not None:
                self.set_seed(seed)

        # ------------------------------------------------------------------ TorchRL API

        def _set_seed(self, seed: int | None) -> None:
            # The project's one seed rule, before TorchRL's seed generator sees the value.
            self._pending_seed = None if seed is None else check_seed(seed, "AtcNfBatchedEnv: seed")

        def _observation(self, los: Any = None, violation: Any = None) -> dict[str, Any]:
            worlds = self.worlds
            flying = worlds.flying
            obs = worlds.observe().copy()
            obs[~flying] = 0.0
            time_fraction = np.minimum(1.0, worlds.time_s / worlds._limit_s)
            state = worlds.obs_spec.global_state(worlds.state, time_fraction, worlds.wind_kt, self.n_slots)
            shape = flying.shape
            return {
                "observation": torch.from_numpy(obs),
                "mask": torch.from_numpy(flying.copy()),
                "los_count": torch.from_numpy(np.zeros(shape, dtype=np.int64) if los is None else los.astype(np.int64)),
                "envelope_violation": torch.from_numpy(np.zeros(shape, dtype=bool) if violation is None else violation),
                "state": torch.from_numpy(state),
                "episode_seed": torch.from_numpy(worlds.episode_seeds.copy()),
            }

        def _pack(self, parts: dict[str, Any], extra: dict[str, Any]) -> TensorDictBase:
            b, m = self.num_envs, self.n_slots
            group = {key: parts[key] for key in ("observation", "mask", "los_count", "envelope_violation")}
            group.update(extra.pop(GROUP, {}))
            out = TensorDict(
                {GROUP: TensorDict(group, batch_size=(b, m)), "state": parts["state"],
                 "episode_seed": parts["episode_seed"], **extra},
                batch_size=(b,),
            )
            return out.to(self.device) if self.device != torch.device("cpu") else out

        def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
            b = self.num_envs
            reset = None if tensordict is None else tensordict.get("_reset", None)
            if reset is None or not self.worlds.started:
                worlds_to_reset = np.arange(b)
            else:
                worlds_to_reset = np.flatnonzero(reset.reshape(b).cpu().numpy())
            seed, self._pending_seed = self._pending_seed, None
            seeds: list[int | None] | None = None
            if seed is not None:
                seeds = [seed + int(k) for k in worlds_to_reset]
            elif self._episode_seeds is not None:
                try:
                    seeds = [int(next(self._episode_seeds)) for _ in worlds_to_reset]
                except StopIteration:
                    raise ValueError("AtcNfBatchedEnv: episode_seeds ran out of seeds") from None
            if len(worlds_to_reset):
                self.worlds.reset_worlds(worlds_to_reset, seeds)
                self.episodes_started += len(worlds_to_reset)
            parts = self._observation()
            flags = self._ended()
            return self._pack(parts, {key: torch.from_numpy(value) for key, value in flags.items()})

        def reset_with_seeds(self, seeds: Any) -> TensorDictBase:
            """Reset every world, world b with episode seed ``seeds[b]`` (B ints: e.g. a
            benchmark split's seeds), and return the first observation."""
            seeds = [int(s) for s in seeds]
            if len(seeds) != self.num_envs:
                raise ValueError(f"seeds: got {len(seeds)}; expected one per world ({self.num_envs})")
            self.worlds.reset_worlds(np.arange(self.num_envs), seeds)
            self.episodes_started += self.num_envs
            self._pending_seed = None
            parts = self._observation()
            return self._pack(parts, {key: torch.from_numpy(value) for key, value in self._ended().items()})

        def _ended(self) -> dict[str, Any]:
            terminated = self.worlds.terminated
            truncated = self.worlds.truncated & ~terminated
            return {
                "done": (terminated | truncated)[:, None].copy(),
                "terminated": terminated[:, None].copy(),
                "truncated": truncated[:, None].copy(),
            }

        def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
            b, m = self.num_envs, self.n_slots
            action = tensordict.get((GROUP, "action")).detach().cpu().numpy()
            clipped, _ = validate_step_actions(action, (b, m, 2), "AtcNfBatchedEnv")
            outcome, trace = self.worlds.step(clipped)
            parts = self._observation(outcome.los_count, trace.violation_steps > 0)
            reward = torch.from_numpy(outcome.rewards.astype(np.float32)[..., None])
            extra: dict[str, Any] = {key: torch.from_numpy(value) for key, value in self._ended().items()}
            extra[GROUP] = {"reward": reward}
            return self._pack(parts, extra)

        def __repr__(self) -> str:
            return f"AtcNfBatchedEnv(num_envs={self.num_envs}, scenario={self.cfg.scenario!r}, slots={self.n_slots})"

    _CLASSES["batched"] = AtcNfBatchedEnv
    return AtcNfBatchedEnv


def __getattr__(name: str) -> Any:
    if name == "AtcNfBatchedEnv":
        return _batched_env_class()
    raise AttributeError(f"module 'atc_nf_env.integrations.torchrl' has no attribute {name!r}")


__all__ = ["AtcNfBatchedEnv", "GROUP", "make_torchrl_env", "refuse_streams"]
