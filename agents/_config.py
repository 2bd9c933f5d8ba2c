"""Command-line flags from a configuration dataclass (CleanRL style, without tyro).

Every field becomes ``--field-name`` (underscores to dashes) with the field's default;
the help text is the field's ``metadata["help"]``. Booleans get ``--flag/--no-flag``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any, Sequence, TypeVar, get_type_hints

T = TypeVar("T")


def arg(default: Any, help: str) -> Any:  # noqa: A002 - mirrors argparse's name
    """A dataclass field with a default and a help text."""
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: default, metadata={"help": help})
    return dataclasses.field(default=default, metadata={"help": help})


def _optional_path(text: str) -> Path | None:
    return None if text.lower() in ("", "none") else Path(text)


def parse_config(cls: type[T], argv: Sequence[str] | None, prog: str, description: str) -> T:
    """Parse ``argv`` into an instance of the dataclass ``cls``."""
    parser = argparse.ArgumentParser(prog=prog, description=description,
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    hints = get_type_hints(cls)
    for f in dataclasses.fields(cls):
        flag = "--" + f.name.replace("_", "-")
        kind = hints[f.name]
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        help_text = f.metadata.get("help", "")
        if kind is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=help_text)
        elif kind is int:
            parser.add_argument(flag, type=int, default=default, help=help_text)
        elif kind is float:
            parser.add_argument(flag, type=float, default=default, help=help_text)
        elif kind is Path:
            parser.add_argument(flag, type=Path, default=default, help=help_text)
        elif kind == (Path | None):
            parser.add_argument(flag, type=_optional_path, default=default, help=help_text)
        else:
            parser.add_argument(flag, type=str, default=default, help=help_text)
    namespace = parser.parse_args(list(argv) if argv is not None else None)
    return cls(**vars(namespace))


def config_dict(config: Any) -> dict[str, Any]:
    """A JSON-ready dict of a configuration dataclass."""
    return {key: (str(value) if isinstance(value, Path) else value) for key, value in dataclasses.asdict(config).items()}


def write_json(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")


def planned_timesteps(model: Any, total_timesteps: int) -> int:
    """Timesteps ``model.learn(total_timesteps)`` will run: rounded up to whole rollouts of
    n_steps × n_envs for on-policy algorithms (PPO, A2C), up to n_envs more for the others."""
    n_envs = int(getattr(model, "n_envs", 1) or 1)
    n_steps = getattr(model, "n_steps", None)
    chunk = int(n_steps) * n_envs if n_steps else n_envs
    return -(-int(total_timesteps) // chunk) * chunk


def progress_callback(total_timesteps: int, enabled: bool) -> Any:
    """An SB3 callback drawing a tqdm progress bar over the timesteps (SB3's own
    ``progress_bar=True`` needs ``rich``, which the ``rl`` extra does not install).

    An on-policy algorithm collects whole rollouts (n_steps × n_envs timesteps), so it
    runs past ``total_timesteps`` up to the next multiple: the bar's total is what will
    really run, and the bar never passes it."""
    from stable_baselines3.common.callbacks import BaseCallback

    class TqdmCallback(BaseCallback):
        def _on_training_start(self) -> None:
            if enabled:
                from tqdm import tqdm

                total = planned_timesteps(self.model, total_timesteps)
                desc = f"timesteps ({total_timesteps} asked, whole rollouts)" if total != total_timesteps else None
                self.bar = tqdm(total=total, unit="step", dynamic_ncols=True, desc=desc)
                self.last = self.model.num_timesteps
            else:
                self.bar = None

        def _on_step(self) -> bool:
            if self.bar is not None:
                done = self.model.num_timesteps - self.last
                self.bar.update(max(0, min(done, self.bar.total - self.bar.n)))
                self.last = self.model.num_timesteps
            return True

        def _on_training_end(self) -> None:
            if self.bar is not None:
                self.bar.close()

    return TqdmCallback()
